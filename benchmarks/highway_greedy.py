"""
Does each driving constraint cost reward? Rule-based drivers with and without the constraints, per traffic density.

A constraint is worth inferring only if breaking it pays: the greedy driver (target speed 60 m/s,
2 m standstill gap, 0.3 s headway) should earn more than the same driver made to respect the
constraint (39.5 m/s; 22 m gap, lane changes only into 22 m gaps). Episodes use the test recordings,
seeds 0..N-1, the same for every driver. "viol" is the share of episodes with a broken constraint,
"feasible" the reward summed up to the first violation of that constraint (the paper's metrics);
"gain" is the greedy driver's return minus the row's, paired by episode, "greedy ahead" the share
of episodes where the greedy driver earns more.

    python benchmarks/highway_greedy.py [--episodes 120] [--no-feasible-start]
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


def evaluate(env: HighwayConstraintEnv, driver: RuleBasedDriver, episodes: int) -> dict[str, np.ndarray]:
    """
    :param env: Environment (its own cost is not used: both constraints are read from info)
    :param driver: Driver to evaluate
    :param episodes: Episodes, reset with seeds ``0..episodes-1``
    :return: Per episode: return, violations, feasible rewards, outcomes and mean speed
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
    return {key: np.array([row[key] for row in rows]) for key in rows[0]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=120)
    parser.add_argument(
        "--feasible-start", action=argparse.BooleanOptionalAction, default=True, help="the envs' feasible_start"
    )
    args = parser.parse_args()
    print(f"feasible_start={args.feasible_start}, {args.episodes} test episodes per row; gain: greedy minus driver, paired")
    print("traffic driver      return  gain (+- se)  greedy ahead  viol v/d   feasible v/d   speed  coll  off  t-out goal")
    for traffic in ("sparse", "dense"):
        env = HighwayConstraintEnv(traffic=traffic, split="test", feasible_start=args.feasible_start)
        results = {name: evaluate(env, RuleBasedDriver(**kwargs), args.episodes) for name, kwargs in DRIVERS.items()}
        for name, r in results.items():
            gain = results["greedy"]["return"] - r["return"]
            m = {key: value.mean() for key, value in r.items()}
            print(
                f"{traffic:<7} {name:<10} {m['return']:6.2f}  {gain.mean():5.2f} ({gain.std() / np.sqrt(len(gain)):.2f})  "
                f"{np.mean(gain > 0):12.2f}  {m['viol_velocity']:.2f}/{m['viol_distance']:.2f}  "
                f"{m['feasible_velocity']:6.2f}/{m['feasible_distance']:6.2f}  {m['speed']:5.1f}  "
                f"{m['collision']:.2f}  {m['off_road']:.2f}  {m['time_out']:.2f}  {m['goal_reached']:.2f}"
            )


if __name__ == "__main__":
    main()
