"""
PPOLagrangian on HalfCheetah-v5 with Safety-Gymnasium's velocity cost (cost 1 when x_velocity > 3.2096),
episode budget 25 over 1000-step episodes, in gradient and in PID multiplier mode, over several seeds.

Each (mode, seed) run is its own process (one torch thread); runs go ``--jobs`` at a time. Every run saves the
per-episode training rewards and costs (from the Monitor, so raw rewards) to ``--out`` as JSON, written
atomically; the summary reads those files, so it can be re-printed without training:

    python benchmarks/ppolag_velocity.py --steps 500000 --seeds 0 1 2 --jobs 2 --out benchmarks/out/velocity
    python benchmarks/ppolag_velocity.py --summarize --out benchmarks/out/velocity

Per run it reports: mean episode cost and reward over the last 10% of training steps, overshoot (highest
10-episode moving average of the episode cost above the budget) and the number of times that moving average
crossed the budget upwards. A zero-action policy's return is printed as the "standing still" reference.
Hyper-parameters: rl-baselines3-zoo's tuned PPO for HalfCheetah (hyperparams/ppo.yml), plus the multiplier.
"""

import argparse
import json
import os
import platform
import time
from concurrent.futures import ProcessPoolExecutor
from datetime import datetime, timezone

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import VecNormalize

from sb3_icrl import PPOLagrangian
from sb3_icrl.common.callbacks import EpisodeCostRecorder
from sb3_icrl.common.envs import VelocityCostWrapper
from sb3_icrl.common.utils import atomic_write_json

BUDGET = 25.0
VELOCITY_THRESHOLD = 3.2096
# rl-baselines3-zoo hyperparams/ppo.yml, HalfCheetah-v3 entry
ZOO_HALFCHEETAH = dict(
    batch_size=64,
    n_steps=512,
    gamma=0.98,
    learning_rate=2.0633e-05,
    ent_coef=0.000401762,
    clip_range=0.1,
    n_epochs=20,
    gae_lambda=0.92,
    max_grad_norm=0.8,
    vf_coef=0.58096,
    policy_kwargs=dict(
        log_std_init=-2, ortho_init=False, activation_fn=th.nn.ReLU, net_arch=dict(pi=[256, 256], vf=[256, 256])
    ),
)
# OmniSafe's PPOLag and CPPOPID defaults
LAGRANGE = {
    "gradient": dict(init=0.001, lr=0.035, optimizer="adam"),
    "pid": dict(init=0.0, kp=0.1, ki=0.01, kd=0.01, d_delay=10, delta_p_ema_alpha=0.95, delta_d_ema_alpha=0.95),
}


def make_env() -> gym.Env:
    return VelocityCostWrapper(gym.make("HalfCheetah-v5"), velocity_threshold=VELOCITY_THRESHOLD)


def run(mode: str, seed: int, steps: int, out: str) -> str:
    th.set_num_threads(1)
    env = VecNormalize(make_vec_env(make_env, n_envs=1, seed=seed), gamma=ZOO_HALFCHEETAH["gamma"])
    model = PPOLagrangian(
        "MlpPolicy",
        env,
        cost_budget=BUDGET,
        budget_statistic="episode",
        lagrange_update=mode,
        lagrange_kwargs=LAGRANGE[mode],
        seed=seed,
        **ZOO_HALFCHEETAH,
    )
    multipliers: list[tuple[int, float]] = []

    class Recorder(EpisodeCostRecorder):
        """Training episodes, the multiplier after each rollout, and a progress line every 25 episodes."""

        def _on_step(self) -> bool:
            n_episodes = len(self.episodes)
            super()._on_step()
            if len(self.episodes) // 25 > n_episodes // 25:
                recent = self.recent(25)
                print(
                    f"[{mode} seed {seed}] {self.num_timesteps} steps: reward {recent[:, 1].mean():.0f} "
                    f"cost {recent[:, 2].mean():.1f} lambda {model.lagrange_multiplier.value[0]:.3f}",
                    flush=True,
                )
            return True

        def _on_rollout_end(self) -> None:
            multipliers.append((self.num_timesteps, float(model.lagrange_multiplier.value[0])))

    recorder = Recorder()
    start = time.time()
    model.learn(steps, callback=recorder)
    episodes = [(step, reward, cost) for step, reward, cost, _ in recorder.episodes]
    result = dict(
        mode=mode,
        seed=seed,
        steps=steps,
        wall_time_s=time.time() - start,
        episodes=episodes,
        multipliers=multipliers,
        hyperparameters={**{k: v for k, v in ZOO_HALFCHEETAH.items() if k != "policy_kwargs"}, "lagrange": LAGRANGE[mode]},
        machine=platform.processor() or platform.machine(),
        date=datetime.now(timezone.utc).isoformat(timespec="seconds"),
    )
    path = os.path.join(out, f"{mode}_seed{seed}.json")
    atomic_write_json(path, result)
    return path


def standing_still_return(n_episodes: int = 3) -> float:
    env = make_env()
    returns = []
    for episode in range(n_episodes):
        env.reset(seed=episode)
        total, done = 0.0, False
        while not done:
            _, reward, terminated, truncated, _ = env.step(np.zeros(env.action_space.shape))
            total += float(reward)
            done = terminated or truncated
        returns.append(total)
    return float(np.mean(returns))


def _up_crossings(series: np.ndarray, level: float) -> int:
    """Times the series goes from <= level to > level (starting above counts as one)."""
    above = series > level
    return int(np.sum(above[1:] & ~above[:-1]) + (above[0] if len(above) else 0))


def summarize(out: str) -> None:
    files = sorted(name for name in os.listdir(out) if name.endswith(".json"))
    if not files:
        raise SystemExit(f"No results in {out}: run the benchmark first.")
    print(f"standing-still (zero action) return: {standing_still_return():.1f}")
    header = (
        "mode      seed  steps    last10% cost  last10% reward  final lambda  overshoot  crossings (>25, >27.5)"
        "  wall(min)  <=27.5"
    )
    print(header)
    per_mode: dict[str, list[tuple[float, float]]] = {}
    for name in files:
        with open(os.path.join(out, name)) as handle:
            result = json.load(handle)
        episodes = np.array(result["episodes"], dtype=np.float64).reshape(-1, 3)
        last = episodes[episodes[:, 0] > 0.9 * result["steps"]]
        costs = episodes[:, 2]
        window = 10
        moving = np.convolve(costs, np.ones(window) / window, mode="valid") if len(costs) >= window else costs
        crossings, band_crossings = (_up_crossings(moving, level) for level in (BUDGET, 1.1 * BUDGET))
        overshoot = float(max(0.0, moving.max() - BUDGET)) if len(moving) else 0.0
        last_cost, last_reward = float(last[:, 2].mean()), float(last[:, 1].mean())
        per_mode.setdefault(result["mode"], []).append((last_cost, last_reward))
        print(
            f"{result['mode']:9s} {result['seed']:4d}  {result['steps']:7d}  {last_cost:12.1f}  {last_reward:14.1f}"
            f"  {result['multipliers'][-1][1]:12.3f}  {overshoot:9.1f}  {crossings:9d} {band_crossings:12d}"
            f"  {result['wall_time_s'] / 60:9.1f}"
            f"  {'yes' if last_cost <= 1.1 * BUDGET else 'NO'}"
        )
    for mode, values in per_mode.items():
        costs, rewards = np.array(values).T
        print(
            f"{mode:9s} mean +- std over {len(values)} seeds: cost {costs.mean():.1f} +- {costs.std():.1f}, "
            f"reward {rewards.mean():.1f} +- {rewards.std():.1f}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=500_000)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--modes", nargs="+", default=["gradient", "pid"], choices=sorted(LAGRANGE))
    parser.add_argument("--jobs", type=int, default=2, help="runs in parallel (one core each)")
    parser.add_argument("--out", default="benchmarks/out/velocity")
    parser.add_argument("--summarize", action="store_true", help="only print the summary of saved runs")
    args = parser.parse_args()
    os.makedirs(args.out, exist_ok=True)
    if not args.summarize:
        runs = [(mode, seed) for seed in args.seeds for mode in args.modes]
        with ProcessPoolExecutor(max_workers=args.jobs) as pool:
            futures = [pool.submit(run, mode, seed, args.steps, args.out) for mode, seed in runs]
            for future in futures:
                print("saved", future.result(), flush=True)
    summarize(args.out)


if __name__ == "__main__":
    main()
