"""
Does each driving constraint cost reward? Rule-based drivers with and without the constraints, per traffic density.

A constraint is worth inferring only if breaking it pays: the greedy driver (target speed 60 m/s,
2 m standstill gap, 0.3 s headway) should earn more than the same driver made to respect the
constraint (39.5 m/s; 22 m gap, lane changes only into 22 m gaps). Episodes use the test recordings,
seeds 0..N-1, the same for every driver. "viol" is the share of episodes with a broken constraint,
"feasible" the reward summed up to the first violation of that constraint (the paper's metrics).

    python benchmarks/highway_greedy.py [--episodes 60]
"""

import argparse

import numpy as np

from sb3_icrl.envs.highway import HighwayConstraintEnv
from sb3_icrl.envs.highway.drivers import RuleBasedDriver

DRIVERS: dict[str, dict] = {
    "greedy": {"target_speed": 60.0, "min_gap": 2.0, "lane_change_gap": 5.0},
    "speed<=40": {"target_speed": 39.5, "min_gap": 2.0, "lane_change_gap": 5.0},
    "gap>=20": {"target_speed": 60.0, "min_gap": 22.0, "lane_change_gap": 22.0},
    "both": {"target_speed": 39.5, "min_gap": 22.0, "lane_change_gap": 22.0},
}
OUTCOMES = ("collision", "off_road", "time_out", "goal_reached")


def evaluate(env: HighwayConstraintEnv, driver: RuleBasedDriver, episodes: int) -> dict[str, float]:
    """
    :param env: Environment (its own cost is not used: both constraints are read from info)
    :param driver: Driver to evaluate
    :param episodes: Episodes, reset with seeds ``0..episodes-1``
    :return: Means over episodes of the return, violations, feasible rewards, outcomes and speed
    """
    rows = []
    for seed in range(episodes):
        obs, _ = env.reset(seed=seed)
        driver.reset()
        done, total, speeds = False, 0.0, []
        broken = {"velocity": False, "distance": False}
        feasible = {"velocity": 0.0, "distance": 0.0}
        while not done:
            obs, reward, done, _, info = env.step(driver(obs))
            total += reward
            speeds.append(info["ego_speed"])
            for name in broken:
                broken[name] |= info[f"cost_{name}"] > 0
                feasible[name] += 0.0 if broken[name] else reward
        rows.append(
            {"return": total, "speed": float(np.mean(speeds)), **{k: float(info[k]) for k in OUTCOMES}}
            | {f"viol_{k}": float(v) for k, v in broken.items()}
            | {f"feasible_{k}": v for k, v in feasible.items()}
        )
    return {key: float(np.mean([row[key] for row in rows])) for key in rows[0]} | {
        "return_std": float(np.std([row["return"] for row in rows]))
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=60)
    args = parser.parse_args()
    header = "traffic driver       return        viol v/d   feasible v/d   speed  collision off-road time-out goal"
    print(header)
    for traffic in ("sparse", "dense"):
        env = HighwayConstraintEnv(traffic=traffic, split="test")
        for name, kwargs in DRIVERS.items():
            r = evaluate(env, RuleBasedDriver(**kwargs), args.episodes)
            print(
                f"{traffic:<7} {name:<10} {r['return']:6.2f} +- {r['return_std']:4.2f}  "
                f"{r['viol_velocity']:.2f}/{r['viol_distance']:.2f}  "
                f"{r['feasible_velocity']:6.2f}/{r['feasible_distance']:5.2f}  "
                f"{r['speed']:5.1f}  {r['collision']:9.2f} {r['off_road']:8.2f} {r['time_out']:8.2f} {r['goal_reached']:4.2f}"
            )


if __name__ == "__main__":
    main()
