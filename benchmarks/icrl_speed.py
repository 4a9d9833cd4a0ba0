"""
Training speed of PPO, PPOLagrangian, MECL and VICRL on a benchmark env (BlockedHalfCheetah-v0 unless ``--env``) at
the same settings, and where the time goes.

All four use the PPO settings of the env's shipped VICRL recipe (``zoo_hyperparams/vicrl.yml``: envs,
rollout length, minibatch, epochs, networks) and the same VecEnv stack as ``train.py`` (DummyVecEnv, Monitor,
VecNormalize). PPO is SB3's; PPOLagrangian learns on the env's true cost with the recipe's PID multiplier; MECL and
VICRL are their full recipes on the shipped demonstrations. Runs are interleaved (PPO, PPOLag, MECL, VICRL, PPO, ...)
with one torch thread, so that machine noise hits all alike. Speed is env steps over the CPU time of this process in
``learn`` (what a shared machine's load does not stretch) and over its wall time; ratios are per round, with their
median and range.

Each run is also timed by part: every timed function books the time spent in it, less the time of timed functions it
calls, to one category; ``learn`` itself is the root, so the categories add up to the wall time of ``learn`` (the
coverage line says how closely; the timers cost about 1 us a call).

    python benchmarks/icrl_speed.py --steps 20480 --repeats 2
    python benchmarks/icrl_speed.py --steps 10240 -params n_envs:1 n_steps:512   # the recipe's settings overridden
    python benchmarks/icrl_speed.py --env BlockedAnt-v0 --steps 20480            # another env's recipes
    python benchmarks/icrl_speed.py --steps 20480 --algos mecl --against n_envs:16 n_steps:256 batch_size:512 n_epochs:10
                                                                                 # a second recipe, interleaved
    python benchmarks/icrl_speed.py --steps 40960 --algos minimal ppolag mecl -params n_envs:16 n_steps:256 ...
                                                                                 # against the minimal-PPO ceiling

``minimal`` is the plain-torch PPO of ``benchmarks/minimal_ppo.py`` at the same PPO settings on the same VecEnv stack:
the ceiling, what a loop with none of SB3's machinery reaches; its parts are timed as its rollouts and its update.
"""

import argparse
import functools
import os
import platform
import statistics
import time
from collections import defaultdict
from collections.abc import Callable
from typing import Any

import torch as th
from minimal_ppo import MinimalPPO
from stable_baselines3 import PPO
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecEnvWrapper

from sb3_icrl import MECL, VICRL, PPOLagrangian
from sb3_icrl.constraints.wrappers import LearnedCostVecEnvWrapper
from sb3_icrl.data.registry import load_demonstrations
from sb3_icrl.hyperparams import algo_kwargs, load_hyperparams, preprocess_hyperparams
from sb3_icrl.icrl.recorder import TrajectoryRecorderVecEnvWrapper
from sb3_icrl.registry import resolve_env_id
from sb3_icrl.zoo.train import StoreDict, create_env

DEFAULT_ENV = "BlockedHalfCheetah-v0"
ALGOS = ("ppo", "ppolag", "mecl", "vicrl", "minimal")
#: The PPO settings every algorithm shares; the rest of an ICRL entry (constraint model, trainer) is the algorithm's
PPO_KEYS = (
    "n_steps",
    "batch_size",
    "n_epochs",
    "gamma",
    "gae_lambda",
    "learning_rate",
    "ent_coef",
    "clip_range",
    "max_grad_norm",
    "vf_coef",
    "policy_kwargs",
)
CATEGORIES = (
    "PPO update (train)",
    "policy and value forwards (rollouts)",
    "rollout loop, callbacks, buffer, GAE",
    "VecEnv stack (DummyVecEnv, VecNormalize, cost wrapper)",
    "trajectory recorder",
    "learned cost",
    "constraint update",
    "env python (wrappers, reward, cost)",
    "MuJoCo physics",
    "learn set-up, logging, other",
)


class SectionTimer:
    """Exclusive wall time per category: a timed call pauses the category of the call it is made from."""

    def __init__(self) -> None:
        self.totals: dict[str, float] = defaultdict(float)
        self.calls: dict[str, int] = defaultdict(int)
        self._stack: list[str] = []
        self._last = 0.0

    def _enter(self, category: str) -> None:
        now = time.perf_counter()
        if self._stack:
            self.totals[self._stack[-1]] += now - self._last
        self._stack.append(category)
        self.calls[category] += 1
        self._last = now

    def _exit(self) -> None:
        now = time.perf_counter()
        self.totals[self._stack.pop()] += now - self._last
        self._last = now

    def wrap(self, category: str, function: Callable[..., Any]) -> Callable[..., Any]:
        """``function`` with its time booked to ``category``."""

        @functools.wraps(function)
        def timed(*args: Any, **kwargs: Any) -> Any:
            self._enter(category)
            try:
                return function(*args, **kwargs)
            finally:
                self._exit()

        return timed

    def patch(self, owner: Any, name: str, category: str) -> None:
        """Time ``owner.name`` (an instance attribute shadows the class's method)."""
        if hasattr(owner, name):
            setattr(owner, name, self.wrap(category, getattr(owner, name)))


def recipe(env_id: str, overrides: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Preprocessed hyper-parameters per algorithm: the VICRL recipe's PPO settings for all, ICRL keys their own."""
    shared = preprocess_hyperparams(load_hyperparams("vicrl", env_id, overrides)[0])
    params: dict[str, dict[str, Any]] = {}
    for algo in ALGOS:
        source = "vicrl" if algo in ("ppo", "ppolag", "minimal") else algo
        entry = preprocess_hyperparams(load_hyperparams(source, env_id, overrides)[0])
        entry.update({key: shared[key] for key in (*PPO_KEYS, "n_envs", "normalize") if key in shared})
        params[algo] = entry
    return params


def build(algo: str, params: dict[str, Any], env_id: str, seed: int, demonstrations: Any) -> BaseAlgorithm | MinimalPPO:
    env, _ = create_env(env_id, params, params["n_envs"], seed, {}, 0.0, None)
    if algo == "minimal":
        if params.get("policy_kwargs"):
            raise ValueError(
                "The minimal PPO has SB3's default [64, 64] nets only: pass policy_kwargs:dict(), not "
                f"{params['policy_kwargs']}."
            )
        return MinimalPPO(env, seed=seed, **{key: params[key] for key in PPO_KEYS if key in params})
    if algo == "ppo":
        return PPO(params["policy"], env, seed=seed, **{key: params[key] for key in PPO_KEYS if key in params})
    if algo == "ppolag":
        kwargs = {key: params[key] for key in (*PPO_KEYS, "lagrange_update", "lagrange_kwargs") if key in params}
        return PPOLagrangian(params["policy"], env, seed=seed, cost_budget=0.0, budget_statistic="step", **kwargs)
    algo_class = {"mecl": MECL, "vicrl": VICRL}[algo]
    return algo_class(params["policy"], env, seed=seed, demonstrations=demonstrations, **algo_kwargs(params))


def instrument(model: BaseAlgorithm | MinimalPPO, timer: SectionTimer) -> None:
    """Time the parts of ``model``'s training loop (instance attributes only: nothing global changes)."""
    timer.patch(model, "train", CATEGORIES[0])
    if isinstance(model, MinimalPPO):
        timer.patch(model, "collect_rollouts", CATEGORIES[2])
        node: VecEnv = model.env
    else:
        _instrument_learner(model, timer)
        node = model.get_env()  # type: ignore[assignment]
    _instrument_env(node, timer)


def _instrument_learner(model: BaseAlgorithm, timer: SectionTimer) -> None:
    timer.patch(model, "collect_rollouts", CATEGORIES[2])
    for name in ("forward", "act", "predict_values", "predict_all_values"):
        timer.patch(model.policy, name, CATEGORIES[1])
    constraint_net = getattr(model, "constraint_net", None)
    if constraint_net is not None:
        timer.patch(constraint_net, "cost", CATEGORIES[5])
        model.icrl_trainer = model._make_trainer()  # type: ignore[attr-defined]  # learn() keeps it
        timer.patch(model.icrl_trainer, "_on_rollout_end", CATEGORIES[6])


def _instrument_env(node: VecEnv, timer: SectionTimer) -> None:
    while True:
        category = CATEGORIES[4] if isinstance(node, TrajectoryRecorderVecEnvWrapper) else CATEGORIES[3]
        for name in ("step_async", "step_wait", "reset"):
            timer.patch(node, name, category)
        if isinstance(node, LearnedCostVecEnvWrapper):
            timer.patch(node, "_hide_true_cost", CATEGORIES[3])
        if not isinstance(node, VecEnvWrapper):
            break
        node = node.venv
    assert isinstance(node, DummyVecEnv), f"expected a DummyVecEnv at the bottom, got {type(node).__name__}"
    for env in node.envs:
        timer.patch(env, "step", CATEGORIES[7])
        timer.patch(env, "reset", CATEGORIES[7])
        timer.patch(env.unwrapped, "do_simulation", CATEGORIES[8])


def measure(algo: str, params: dict[str, Any], env_id: str, steps: int, seed: int, demos: Any) -> tuple[dict, dict]:
    """
    Env steps per second of ``learn(steps)``, on the process's CPU time and on wall time, and the wall time per
    category (model construction is not timed).
    """
    model = build(algo, params, env_id, seed, demos)
    timer = SectionTimer()
    instrument(model, timer)
    learn = timer.wrap(CATEGORIES[9], model.learn)
    start, cpu_start = time.perf_counter(), time.process_time()
    learn(steps)
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu_start
    speeds = {"cpu": model.num_timesteps / cpu, "wall": model.num_timesteps / wall}
    return speeds, {"wall": wall, **{key: timer.totals[key] for key in CATEGORIES}}


def ratio_line(algo: str, peer: str, mine: list[float], theirs: list[float], clock: str, target: float | None = 0.95) -> str:
    """The per-round ratios of two speeds (rounds interleaved), their median and range, and the target they must reach."""
    ratios = [a / b for a, b in zip(mine, theirs, strict=True)]
    median = statistics.median(ratios)
    line = (
        f"{algo} / {peer} ({clock} time): median {median:.3f}, range {min(ratios):.3f}-{max(ratios):.3f} over "
        f"{len(ratios)} rounds ({', '.join(f'{r:.3f}' for r in ratios)})"
    )
    return line + (f"; target >= {target}: {'PASS' if median >= target else 'FAIL'}" if target is not None else "")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=20480, help="env steps per run (a multiple of n_envs x n_steps)")
    parser.add_argument("--repeats", type=int, default=2, help="interleaved rounds of the four algorithms")
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    parser.add_argument("--env", default=DEFAULT_ENV, help="a benchmark env with shipped demonstrations and recipes")
    parser.add_argument("--algos", nargs="+", default=list(ALGOS), choices=ALGOS)
    parser.add_argument("-params", "--hyperparams", nargs="+", type=str, action=StoreDict, default={}, help="overrides k:v")
    parser.add_argument(
        "--against",
        nargs="+",
        type=str,
        action=StoreDict,
        default=None,
        help="a second recipe, these overrides on top of the first: each algorithm runs with both, interleaved, and "
        "the speed of the second over the first's is reported per round",
    )
    args = parser.parse_args()
    th.set_num_threads(args.threads)
    env_id = resolve_env_id(args.env)
    params = recipe(env_id, args.hyperparams)
    demos = load_demonstrations(args.env)
    shared = params["vicrl"]
    print(
        f"{args.env}: n_envs {shared['n_envs']}, n_steps {shared['n_steps']}, batch_size {shared['batch_size']}, "
        f"n_epochs {shared.get('n_epochs', 'SB3 default')}, {args.steps} steps per run, torch threads {args.threads}",
        flush=True,
    )

    recipes = {"": params}
    if args.against is not None:
        recipes["@against"] = recipe(env_id, {**args.hyperparams, **args.against})
        other = recipes["@against"]["vicrl"]
        print(
            f"against: n_envs {other['n_envs']}, n_steps {other['n_steps']}, batch_size {other['batch_size']}, "
            f"n_epochs {other.get('n_epochs', 'SB3 default')} ({args.against})",
            flush=True,
        )
    measure("ppo", params["ppo"], env_id, shared["n_envs"] * shared["n_steps"], 0, demos)  # warm-up
    labels = [algo + suffix for algo in args.algos for suffix in recipes]
    fps: dict[str, dict[str, list[float]]] = {clock: {label: [] for label in labels} for clock in ("cpu", "wall")}
    parts: dict[str, list[dict]] = {label: [] for label in labels}
    for repeat in range(args.repeats):
        for algo in args.algos:
            for suffix, algo_params in recipes.items():
                speeds, run_parts = measure(algo, algo_params[algo], env_id, args.steps, repeat, demos)
                for clock, speed in speeds.items():
                    fps[clock][algo + suffix].append(speed)
                parts[algo + suffix].append(run_parts)
                label = algo + suffix
                print(f"round {repeat} {label:15s} {speeds['cpu']:8.1f} steps/CPU-s {speeds['wall']:8.1f} steps/s", flush=True)

    load = os.getloadavg()
    print(f"\nmachine: {platform.processor() or platform.machine()}, {time.strftime('%Y-%m-%d %H:%M')}, load {load[0]:.2f}")
    for algo in labels:
        cpu, wall = fps["cpu"][algo], fps["wall"][algo]
        print(
            f"{algo:15s} median {statistics.median(cpu):8.1f} steps/CPU-s (range {min(cpu):.0f}-{max(cpu):.0f}), "
            f"{statistics.median(wall):8.1f} steps/s wall (range {min(wall):.0f}-{max(wall):.0f})"
        )
    reference = {"ppolag": "ppo", "mecl": "ppolag", "vicrl": "ppolag"}
    for algo, peer in reference.items():
        if algo in args.algos and peer in args.algos:
            for suffix in recipes:
                for clock in ("cpu", "wall"):
                    mine, theirs = fps[clock][algo + suffix], fps[clock][peer + suffix]
                    print(ratio_line(algo + suffix, peer + suffix, mine, theirs, "CPU" if clock == "cpu" else "wall"))
    if "minimal" in args.algos:  # the ceiling: each learner's share of what the minimal loop reaches
        for algo in (algo for algo in args.algos if algo != "minimal"):
            for suffix in recipes:
                mine, theirs = fps["cpu"][algo + suffix], fps["cpu"][f"minimal{suffix}"]
                print(ratio_line(algo + suffix, f"minimal{suffix}", mine, theirs, "CPU", target=None))
    if len(recipes) > 1:
        for algo in args.algos:
            for clock in ("cpu", "wall"):
                mine, theirs = fps[clock][algo + "@against"], fps[clock][algo]
                print(ratio_line(algo + "@against", algo, mine, theirs, "CPU" if clock == "cpu" else "wall", target=None))

    print("\nshare of wall time (mean over rounds)")
    print(f"{'part':56s}" + "".join(f"{label:>16s}" for label in labels))
    for category in CATEGORIES:
        shares = [statistics.mean(run[category] / run["wall"] for run in parts[label]) for label in labels]
        print(f"{category:56s}" + "".join(f"{100 * share:15.1f}%" for share in shares))
    coverage = [statistics.mean(sum(run[key] for key in CATEGORIES) / run["wall"] for run in parts[label]) for label in labels]
    print(f"{'sum of the parts / wall time':56s}" + "".join(f"{100 * share:15.1f}%" for share in coverage))
    per_step = [statistics.mean(1e6 * run["wall"] / args.steps for run in parts[label]) for label in labels]
    print(f"{'us per env step (wall)':56s}" + "".join(f"{value:16.0f}" for value in per_step))


if __name__ == "__main__":
    main()
