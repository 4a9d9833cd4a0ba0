"""
Bad input gets a clear error, never a silent default or a traceback from deep inside: one table of wrong arguments
across the API and the command lines (each with the exception it raises and a fragment of its message), then the
cases that need more set-up: failed runs, loading another algorithm's model, demonstrations recorded on another
env, ``compare``'s checks before any evaluation and its warning on too few Wilcoxon pairs.
"""

import contextlib
import importlib
import io
import json
import os
import pathlib
import types
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from stable_baselines3 import PPO
from stable_baselines3.common.policies import ActorCriticPolicy

from sb3_icrl import BC2L, GACL, MECL, VICRL, PILagrangian, PPOLagrangian, SACLagrangian
from sb3_icrl.common.costs import CostError, as_cost_array, costs_from_infos
from sb3_icrl.common.saved import CheckedLoadMixin, library_algorithm
from sb3_icrl.constraints import FeasibilityNet
from sb3_icrl.data import Demonstrations, Trajectory, load_demonstrations, save
from sb3_icrl.data.generate import build_dataset
from sb3_icrl.data.serialize import DemonstrationError, check_spaces, load
from sb3_icrl.envs.wrappers import TransitionNoiseWrapper
from sb3_icrl.icrl.base import ICRLAlgorithmMixin, LagrangianICRL
from sb3_icrl.zoo.compare import RunResult, summarise, wilcoxon_warnings
from sb3_icrl.zoo.runs import FAILED_FILE, FINISHED_FILE

# ``sb3_icrl.zoo.train`` and friends are shadowed by functions of the same name in ``sb3_icrl.zoo``
train_module = importlib.import_module("sb3_icrl.zoo.train")
enjoy_module = importlib.import_module("sb3_icrl.zoo.enjoy")
compare_module = importlib.import_module("sb3_icrl.zoo.compare")
data_cli = importlib.import_module("sb3_icrl.data.__main__")
benchmark_cli = importlib.import_module("sb3_icrl.benchmark.cli")
plots_cli = importlib.import_module("sb3_icrl.plots.__main__")

GRID = "sb3_icrl/GridWorldWall-v0"
TINY: dict[str, Any] = {"n_steps": 16, "batch_size": 16, "policy_kwargs": {"net_arch": [4]}}
TRAIN_TINY = [
    "--eval-freq",
    "-1",
    "--verbose",
    "0",
    "-params",
    "n_steps:16",
    "batch_size:16",
    "policy_kwargs:dict(net_arch=[4])",
]
ALGORITHMS = (PPOLagrangian, GACL, BC2L, MECL, VICRL)


class CLIError(Exception):
    """A command that exited with a non-zero status; the message is what it wrote on stderr."""


def run_cli(main: Callable[..., int], argv: list[str]) -> None:
    """Run a command-line entry point in-process; raise :class:`CLIError` with its stderr unless it exits with 0."""
    stderr = io.StringIO()
    with contextlib.redirect_stderr(stderr), contextlib.redirect_stdout(io.StringIO()):
        status: Any
        try:
            status = main(argv)
        except SystemExit as exit_:  # argparse errors
            status = exit_.code
    if status:
        raise CLIError(" ".join(stderr.getvalue().split()))  # one line: argparse wraps its usage


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """Two finished tiny PPO-Lagrangian runs (seeds 0 and 1) and a scratch folder."""
    root = tmp_path_factory.mktemp("bad_inputs")
    for seed in (0, 1):
        argv = ["--algo", "ppolag", "--env", "GridWorldWall-v0", "-n", "32", "--seed", str(seed), "-f", str(root / "logs")]
        run_cli(train_module.main, argv + TRAIN_TINY)
    folder = root / "logs" / "ppolag"
    (root / "a_file").write_text("not a folder")
    return {
        "root": str(root),
        "file": str(root / "a_file"),
        "run0": str(folder / "GridWorldWall-v0_1"),
        "run1": str(folder / "GridWorldWall-v0_2"),
    }


def _grid_trajectory(obs: Any = (0, 1, 2), costs: Any = (0.0, 0.0)) -> Trajectory:
    return Trajectory(
        obs=np.asarray(obs),
        acts=np.ones(2, dtype=np.int64),
        infos=None,
        terminal=False,
        rews=np.zeros(2),
        costs=np.asarray(costs),
    )


def _box_trajectory(value: float) -> Trajectory:
    obs = np.zeros((3, 2), dtype=np.float32)
    obs[1, 0] = value
    return Trajectory(
        obs=obs, acts=np.zeros((2, 1), dtype=np.float32), infos=None, terminal=False, rews=np.zeros(2), costs=np.zeros(2)
    )


def _ppolag(**kwargs: Any) -> PPOLagrangian:
    return PPOLagrangian("MlpPolicy", GRID, **{**TINY, **kwargs})


def _icrl(algorithm: type, **kwargs: Any) -> Any:
    return algorithm("MlpPolicy", GRID, **{**TINY, **kwargs})


def _train(root: str, *argv: str) -> None:
    run_cli(train_module.main, ["--algo", "ppolag", "--env", "GridWorldWall-v0", "-f", f"{root}/scratch", *TRAIN_TINY, *argv])


def _train_icrl(root: str, *argv: str) -> None:
    run_cli(train_module.main, ["--algo", "mecl", "--env", "GridWorldWall-v0", "-f", f"{root}/scratch", "-n", "16", *argv])


def _enjoy(*argv: str) -> None:
    run_cli(enjoy_module.main, ["--algo", "ppolag", "--env", "GridWorldWall-v0", "--no-render", "--verbose", "0", *argv])


def _generate(root: str, *argv: str) -> None:
    base = ["generate", "--env", "GridWorldWall-v0", "--expert", "pilag", "--n", "2", "--out", f"{root}/demos.npz"]
    run_cli(data_cli.main, [*base, *argv])


def _write(path: str, text: str) -> str:
    pathlib.Path(path).write_text(text)
    return path


# (id, call(runs), exception type, fragment of the message)
BAD_INPUTS: list[tuple[str, Callable[[dict[str, str]], Any], type[BaseException], str]] = [
    # ---------------------------------------------------------------- PPOLagrangian: constructor, learn, budgets
    ("ppolag-negative-budget", lambda r: _ppolag(cost_budget=-1.0), ValueError, "`cost_budget` must be >= 0"),
    ("ppolag-negative-budget-of-two", lambda r: _ppolag(cost_budget=[0.0, -0.1]), ValueError, "must be >= 0"),
    ("ppolag-nan-budget", lambda r: _ppolag(cost_budget=float("nan")), ValueError, "finite float"),
    ("ppolag-empty-budget", lambda r: _ppolag(cost_budget=[]), ValueError, "non-empty sequence"),
    ("ppolag-text-budget", lambda r: _ppolag(cost_budget="abc"), ValueError, "got 'abc'"),
    ("ppolag-mapping-budget", lambda r: _ppolag(cost_budget={"a": 1}), ValueError, "`cost_budget` must be"),
    ("ppolag-budget-statistic", lambda r: _ppolag(budget_statistic="mean"), ValueError, "Unknown `budget_statistic`"),
    ("ppolag-gamma-above-1", lambda r: _ppolag(gamma=2.0), ValueError, "`gamma` must be in [0, 1]"),
    ("ppolag-cost-gamma", lambda r: _ppolag(cost_gamma=1.5), ValueError, "`cost_gamma` must be in [0, 1]"),
    ("ppolag-cost-gae-lambda", lambda r: _ppolag(cost_gae_lambda=-0.1), ValueError, "`cost_gae_lambda` must be in [0, 1]"),
    ("ppolag-cost-vf-coef", lambda r: _ppolag(cost_vf_coef=-1.0), ValueError, "`cost_vf_coef` must be >= 0"),
    ("ppolag-cost-info-key", lambda r: _ppolag(cost_info_key=3), TypeError, "`cost_info_key`"),
    ("ppolag-stats-window", lambda r: _ppolag(stats_window_size=0), ValueError, "`stats_window_size` must be >= 1"),
    ("ppolag-cost-fn", lambda r: _ppolag(cost_fn=3), TypeError, "`cost_fn` must be callable"),
    (
        "ppolag-plain-policy",
        lambda r: PPOLagrangian(ActorCriticPolicy, GRID, **TINY),  # type: ignore[arg-type]
        TypeError,
        "needs a CostActorCriticPolicy",
    ),
    ("ppolag-n-costs", lambda r: _ppolag(policy_kwargs={"n_costs": 2}), ValueError, "disagrees with the 1 budget"),
    (
        "ppolag-multiplier-update",
        lambda r: _ppolag(lagrange_update="newton"),
        ValueError,
        "Unknown Lagrange multiplier update",
    ),
    ("ppolag-multiplier-lr", lambda r: _ppolag(lagrange_kwargs={"lr": -1}), ValueError, "learning rate must be >= 0"),
    (
        "ppolag-multiplier-lr-nan",
        lambda r: _ppolag(lagrange_kwargs={"lr": float("nan")}),
        ValueError,
        "learning rate must be >= 0",
    ),
    (
        "ppolag-multiplier-init-nan",
        lambda r: _ppolag(lagrange_kwargs={"init": float("nan")}),
        ValueError,
        "Initial multipliers",
    ),
    (
        "ppolag-multiplier-above-bound",
        lambda r: _ppolag(lagrange_kwargs={"init": 5.0, "upper_bound": 1.0}),
        ValueError,
        "exceed `upper_bound`",
    ),
    (
        "ppolag-multiplier-bound-nan",
        lambda r: _ppolag(lagrange_kwargs={"upper_bound": float("nan")}),
        ValueError,
        "`upper_bound` must be >= 0",
    ),
    (
        "ppolag-multiplier-optimizer",
        lambda r: _ppolag(lagrange_kwargs={"optimizer": "rmsprop"}),
        ValueError,
        "Unknown multiplier optimizer",
    ),
    ("ppolag-multiplier-kwarg", lambda r: _ppolag(lagrange_kwargs={"bogus": 1}), TypeError, "Bad `lagrange_kwargs`"),
    (
        "ppolag-pid-gain-nan",
        lambda r: _ppolag(lagrange_update="pid", lagrange_kwargs={"kp": 0.1, "ki": float("nan")}),
        ValueError,
        "PID gains must be >= 0",
    ),
    ("ppolag-pid-delay", lambda r: _ppolag(lagrange_update="pid", lagrange_kwargs={"d_delay": 0}), ValueError, "`d_delay`"),
    ("ppolag-learn-negative", lambda r: _ppolag().learn(-5), ValueError, "`total_timesteps` must be a finite number >= 0"),
    ("ppolag-learn-nan", lambda r: _ppolag().learn(float("nan")), ValueError, "`total_timesteps`"),  # type: ignore[arg-type]
    ("ppolag-learn-text", lambda r: _ppolag().learn("100"), TypeError, "`total_timesteps` must be a number"),  # type: ignore[arg-type]
    ("ppolag-set-negative-budget", lambda r: _ppolag().set_cost_budget(-1.0), ValueError, "budget(s) >= 0"),
    ("ppolag-set-budget-shape", lambda r: _ppolag().set_cost_budget([1.0, 2.0]), ValueError, "Expected 1 finite budget"),
    ("ppolag-set-cost-fn", lambda r: _ppolag().set_cost_fn("cost"), TypeError, "`cost_fn` must be callable"),  # type: ignore[arg-type]
    # ---------------------------------------------------------------- ICRL constructors and learn
    ("icrl-negative-budget", lambda r: _icrl(BC2L, cost_budget=-0.5), ValueError, "`cost_budget` must be >= 0"),
    ("icrl-budget-word", lambda r: _icrl(MECL, cost_budget="expert-ish"), ValueError, "a float or 'expert'"),
    (
        "icrl-expert-budget-per-episode",
        lambda r: _icrl(MECL, cost_budget="expert", budget_statistic="episode"),
        ValueError,
        "needs budget_statistic='step'",
    ),
    ("icrl-cost-fn", lambda r: _icrl(VICRL, cost_fn=lambda o, a: o), ValueError, "learns its cost"),
    ("icrl-constraint-steps", lambda r: _icrl(MECL, constraint_steps=0), ValueError, "must be >= 1"),
    ("icrl-update-every", lambda r: _icrl(BC2L, update_every=0), ValueError, "`update_every`"),
    ("icrl-nominal-trajectories", lambda r: _icrl(MECL, n_nominal_trajectories=0), ValueError, "`n_nominal_trajectories`"),
    ("icrl-constraint-batch", lambda r: _icrl(MECL, constraint_batch_size=-5), ValueError, "`batch_size` must be >= 1"),
    (
        "icrl-trainer-kwarg",
        lambda r: _icrl(MECL, trainer_kwargs={"bogus": 1}),
        TypeError,
        "Bad `trainer_kwargs` for MECLTrainer",
    ),
    (
        "icrl-learning-rate-decay",
        lambda r: _icrl(MECL, trainer_kwargs={"learning_rate_decay": 0.0}),
        ValueError,
        "`learning_rate_decay` must be in (0, 1]",
    ),
    (
        "icrl-match-tolerance",
        lambda r: _icrl(VICRL, trainer_kwargs={"match_tolerance": -1.0}),
        ValueError,
        "`match_tolerance`",
    ),
    ("icrl-nominal-memory", lambda r: _icrl(BC2L, trainer_kwargs={"nominal_memory": -1}), ValueError, "`nominal_memory`"),
    ("icrl-trainer-class", lambda r: _icrl(MECL, trainer_class=object), TypeError, "subclass of ICRLTrainer"),
    (
        "icrl-constraint-lr",
        lambda r: _icrl(MECL, constraint_learning_rate=0.0),
        ValueError,
        "`constraint_learning_rate` must be > 0",
    ),
    (
        "icrl-net-and-kwargs",
        lambda r: _icrl(MECL, constraint_net=FeasibilityNet(49, 4), constraint_net_kwargs={"x": 1}),
        ValueError,
        "not both",
    ),
    ("icrl-net-kwarg", lambda r: _icrl(MECL, constraint_net_kwargs={"bogus": 1}), TypeError, "bogus"),
    (
        "icrl-hidden-negative",
        lambda r: _icrl(MECL, constraint_net_kwargs={"hidden_sizes": [-1]}),
        ValueError,
        "`hidden_sizes` must be a list of layer widths",
    ),
    (
        "icrl-hidden-not-a-list",
        lambda r: _icrl(BC2L, constraint_net_kwargs={"hidden_sizes": 64}),
        ValueError,
        "`hidden_sizes`",
    ),
    ("icrl-obs-select", lambda r: _icrl(MECL, constraint_net_kwargs={"obs_select_dim": [99]}), ValueError, "outside the 49"),
    ("icrl-net-spaces", lambda r: _icrl(MECL, constraint_net=FeasibilityNet(3, 4)), ValueError, "takes 3 observation"),
    ("vicrl-prior", lambda r: _icrl(VICRL, prior=(0.0, 1.0)), ValueError, "`prior` is (alpha0, beta0)"),
    ("vicrl-kl-coef", lambda r: _icrl(VICRL, kl_coef=-1.0), ValueError, "`kl_coef` must be >= 0"),
    ("vicrl-cost-mode", lambda r: _icrl(VICRL, cost_mode="median"), ValueError, "Unknown cost mode"),
    ("vicrl-confidence", lambda r: _icrl(VICRL, confidence=1.5), ValueError, "`confidence` must be in (0, 1)"),
    ("gacl-cost-budget", lambda r: _icrl(GACL, cost_budget=0.1), TypeError, "cost_budget"),
    ("icrl-demonstrations-type", lambda r: _icrl(MECL, demonstrations=42), TypeError, "`demonstrations` must be"),
    (
        "icrl-demonstrations-unknown",
        lambda r: _icrl(MECL, demonstrations="NoSuchEnv-v0"),
        DemonstrationError,
        "No demonstrations named 'NoSuchEnv-v0'",
    ),
    ("icrl-demonstrations-empty", lambda r: _icrl(MECL, demonstrations=[]), DemonstrationError, "hold no trajectory"),
    (
        "icrl-demonstrations-other-env",
        lambda r: _icrl(MECL, demonstrations="GridWorldSquare-v0"),
        DemonstrationError,
        "recorded on 'sb3_icrl/GridWorldSquare-v0', not on the target env 'sb3_icrl/GridWorldWall-v0'",
    ),
    ("icrl-learn-without-demonstrations", lambda r: _icrl(BC2L).learn(16), ValueError, "has no demonstrations"),
    (
        "icrl-learn-negative",
        lambda r: _icrl(GACL, demonstrations="GridWorldWall-v0").learn(-3),
        ValueError,
        "`total_timesteps`",
    ),
    # ---------------------------------------------------------------- per-step costs
    (
        "cost-negative-in-info",
        lambda r: costs_from_infos([{"cost": -1.0}], "cost", 1, ["Env-v0"]),
        CostError,
        "reported a negative cost",
    ),
    ("cost-nan-in-info", lambda r: costs_from_infos([{"cost": float("nan")}], "cost", 1, ["Env-v0"]), CostError, "non-finite"),
    (
        "cost-inf-in-second-env",
        lambda r: costs_from_infos([{"cost": 0.0}, {"cost": np.inf}], "cost", 1, ["Env-v0", "Other-v0"]),
        CostError,
        "'Other-v0' (env index 1) reported a non-finite cost",
    ),
    (
        "cost-numpy-negative-in-info",
        lambda r: costs_from_infos([{"cost": np.float64(-0.5)}], "cost", 1, ["Env-v0"]),
        CostError,
        "reported a negative cost",
    ),
    (
        "cost-beyond-float32-in-info",
        lambda r: costs_from_infos([{"cost": 1e39}], "cost", 1, ["Env-v0"]),
        CostError,
        "beyond float32's range",
    ),
    ("cost-text-in-info", lambda r: costs_from_infos([{"cost": "0.5"}], "cost", 1, ["Env-v0"]), CostError, "not numbers"),
    ("cost-word-in-info", lambda r: costs_from_infos([{"cost": "high"}], "cost", 1, ["Env-v0"]), CostError, "not numbers"),
    (
        "cost-missing-in-info",
        lambda r: costs_from_infos([{"reward": 1}], "cost", 1, ["Env-v0"]),
        CostError,
        "did not report a cost",
    ),
    (
        "cost-vector-length",
        lambda r: costs_from_infos([{"cost": [0.0, 1.0]}], "cost", 1, ["Env-v0"]),
        CostError,
        "shape (1, 2)",
    ),
    ("cost-fn-negative", lambda r: as_cost_array(np.array([-0.5]), 1, 1, "cost_fn"), CostError, "negative costs"),
    ("cost-fn-shape", lambda r: as_cost_array(np.zeros(3), 2, 1, "cost_fn"), CostError, "expected (2,) or (2, 1)"),
    # ---------------------------------------------------------------- demonstrations
    (
        "save-nan-observations",
        lambda r: save(f"{r['root']}/nan.npz", [_box_trajectory(np.nan)]),
        DemonstrationError,
        "`obs` holds NaN or infinite values",
    ),
    (
        "save-nan-costs",
        lambda r: save(f"{r['root']}/nan_costs.npz", [_grid_trajectory(costs=(np.nan, 0.0))]),
        DemonstrationError,
        "`costs` holds NaN",
    ),
    (
        "save-negative-costs",
        lambda r: save(f"{r['root']}/neg.npz", [_grid_trajectory(costs=(-1.0, 0.0))]),
        DemonstrationError,
        "`costs` holds negative values",
    ),
    ("save-nothing", lambda r: save(f"{r['root']}/empty.npz", []), DemonstrationError, "list of trajectories is empty"),
    (
        "save-metadata",
        lambda r: save(f"{r['root']}/meta.npz", [_grid_trajectory()], {"f": object()}),
        DemonstrationError,
        "JSON-serialisable",
    ),
    (
        "nan-demonstrations-in-bounds-check",
        lambda r: check_spaces(
            _box_trajectory(np.nan).obs,
            np.zeros((2, 1), np.float32),
            types.SimpleNamespace(observation_space=spaces.Box(-1, 1, (2,)), action_space=spaces.Box(-1, 1, (1,))),  # type: ignore[arg-type]
        ),
        DemonstrationError,
        "values of the observations are NaN or infinite",
    ),
    (
        "out-of-bounds-demonstrations",
        lambda r: check_spaces(
            _box_trajectory(5.0).obs,
            np.zeros((2, 1), np.float32),
            types.SimpleNamespace(observation_space=spaces.Box(-1, 1, (2,)), action_space=spaces.Box(-1, 1, (1,))),  # type: ignore[arg-type]
        ),
        DemonstrationError,
        "lie outside the bounds",
    ),
    ("load-missing-file", lambda r: load(f"{r['root']}/none.npz"), DemonstrationError, "No demonstration file"),
    (
        "load-other-env",
        lambda r: load_demonstrations("GridWorldSquare-v0", env=GRID),
        DemonstrationError,
        "pass `allow_env_mismatch=True`",
    ),
    (
        "load-fraction-not-shipped",
        lambda r: load_demonstrations("GridWorldWall-v0", violating_fraction=1.5),
        DemonstrationError,
        "violating_fraction=1.5",
    ),
    (
        "load-fraction-with-path",
        lambda r: load_demonstrations(f"{r['root']}/x.npz", violating_fraction=0.2),
        DemonstrationError,
        "drop the argument",
    ),
    (
        "trajectory-int-rewards",
        lambda r: Trajectory(np.zeros(3), np.zeros(2), None, False, np.zeros(2, int), np.zeros(2)),
        ValueError,
        "`rews` must be a float numpy array",
    ),
    (
        "trajectory-lengths",
        lambda r: Trajectory(np.zeros(2), np.zeros(2), None, False, np.zeros(2), np.zeros(2)),
        ValueError,
        "one more observation than actions",
    ),
    (
        "generate-zero-trajectories",
        lambda r: build_dataset(f"{r['root']}/g.npz", GRID, "pilag", 0),
        ValueError,
        "`n_trajectories` must be >= 1",
    ),
    (
        "generate-random-action-prob",
        lambda r: build_dataset(f"{r['root']}/g.npz", GRID, "pilag", 2, random_action_prob=2.0),
        ValueError,
        "`random_action_prob` is a probability",
    ),
    (
        "generate-violating-fraction",
        lambda r: build_dataset(f"{r['root']}/g.npz", GRID, "pilag", 2, violating_fraction=1.5),
        ValueError,
        "`violating_fraction` is a share",
    ),
    (
        "generate-max-attempts",
        lambda r: build_dataset(f"{r['root']}/g.npz", GRID, "pilag", 2, max_attempts=0),
        ValueError,
        "`max_attempts` (0) must be at least",
    ),
    (
        "data-cli-out-under-a-file",
        lambda r: _generate(r["root"], "--out", f"{r['file']}/x.npz"),
        CLIError,
        "is a file, not a folder",
    ),
    (
        "data-cli-out-not-npz",
        lambda r: _generate(r["root"], "--out", f"{r['root']}/d.txt"),
        CLIError,
        "d.txt' does not end in .npz: the demonstrations are an .npz archive (with a .json sidecar beside it); pass --out",
    ),
    ("data-cli-negative-seed", lambda r: _generate(r["root"], "--seed", "-3"), CLIError, "--seed must be an integer >= 0"),
    ("data-cli-env-kwargs", lambda r: _generate(r["root"], "--env-kwargs", "{bad"), CLIError, "argument --env-kwargs"),
    (
        "data-cli-missing-expert",
        lambda r: _generate(r["root"], "--expert", f"{r['root']}/none.zip"),
        CLIError,
        "No expert file",
    ),
    (
        "data-cli-info-missing",
        lambda r: run_cli(data_cli.main, ["info", f"{r['root']}/none.npz"]),
        CLIError,
        "No demonstration file",
    ),
    # ---------------------------------------------------------------- environments and planners
    (
        "env-cost-threshold-nan",
        lambda r: gym.make("sb3_icrl/BlockedHalfCheetah-v0", cost_threshold=float("nan")),
        ValueError,
        "`cost_threshold` must be a finite float",
    ),
    (
        "env-cost-threshold-text",
        lambda r: gym.make("sb3_icrl/BlockedHalfCheetah-v0", cost_threshold="abc"),
        TypeError,
        "`cost_threshold` must be a finite float, got str",
    ),
    (
        "env-cost-threshold-inf",
        lambda r: gym.make("sb3_icrl/BlockedAnt-v0", cost_threshold=float("inf")),
        ValueError,
        "finite float",
    ),
    ("env-grid-map", lambda r: gym.make(GRID, map_name="maze"), ValueError, "Unknown grid map 'maze'"),
    ("env-grid-slip", lambda r: gym.make(GRID, slip_prob=1.5), ValueError, "`slip_prob` is a probability"),
    ("env-grid-goal-reward", lambda r: gym.make(GRID, goal_reward=float("nan")), ValueError, "`goal_reward` must be finite"),
    ("env-grid-no-goal", lambda r: gym.make("sb3_icrl/GridWorld-v0", desc=["S..", "..."]), ValueError, "exactly one 'G'"),
    ("env-grid-ragged", lambda r: gym.make("sb3_icrl/GridWorld-v0", desc=["S..", ".G"]), ValueError, "same, non-zero length"),
    (
        "env-grid-character",
        lambda r: gym.make("sb3_icrl/GridWorld-v0", desc=["S.Z", "..G"]),
        ValueError,
        "Unknown map characters",
    ),
    (
        "env-noise-negative",
        lambda r: TransitionNoiseWrapper(gym.make("sb3_icrl/BlockedHalfCheetah-v0"), sigma=-1.0),
        ValueError,
        "`sigma` is a standard deviation",
    ),
    ("env-noise-discrete", lambda r: TransitionNoiseWrapper(gym.make(GRID), sigma=0.1), TypeError, "continuous states"),
    ("pilag-gamma", lambda r: PILagrangian(gym.make(GRID), gamma=1.0), ValueError, "`gamma` must be in [0, 1)"),
    ("pilag-negative-budget", lambda r: PILagrangian(gym.make(GRID), cost_budget=-1.0), ValueError, "`cost_budget` must be"),
    ("pilag-learn-negative", lambda r: PILagrangian(gym.make(GRID)).learn(-1), ValueError, "`total_iterations` must be"),
    ("pilag-learn-zero", lambda r: PILagrangian(gym.make(GRID)).learn(0), ValueError, "integer >= 1"),
    ("pilag-continuous-env", lambda r: PILagrangian(gym.make("sb3_icrl/BlockedHalfCheetah-v0")), TypeError, "plans on tables"),
    ("constraint-net-actions", lambda r: FeasibilityNet(2, 1).cost(np.zeros((3, 2)), None), ValueError, "pass the actions"),
    # ---------------------------------------------------------------- train
    (
        "train-zero-steps",
        lambda r: _train(r["root"], "-n", "0"),
        CLIError,
        "argument -n/--n-timesteps: expected an integer > 0",
    ),
    ("train-negative-steps", lambda r: _train(r["root"], "-n", "-5"), CLIError, "expected an integer > 0, got '-5'"),
    (
        "train-negative-seed",
        lambda r: _train(r["root"], "--seed", "-7"),
        CLIError,
        "argument --seed: expected an integer >= 0",
    ),
    (
        "train-negative-noise",
        lambda r: _train(r["root"], "--transition-noise", "-0.1"),
        CLIError,
        "argument --transition-noise: expected a finite number >= 0",
    ),
    ("train-nan-noise", lambda r: _train(r["root"], "--transition-noise", "nan"), CLIError, "expected a finite number >= 0"),
    (
        "train-violating-fraction",
        lambda r: _train_icrl(r["root"], "--violating-fraction", "1.5"),
        CLIError,
        "argument --violating-fraction: expected a fraction in [0, 1)",
    ),
    (
        "train-fraction-not-shipped",
        lambda r: _train_icrl(r["root"], "--violating-fraction", "0.3"),
        CLIError,
        "violating_fraction=0.3",
    ),
    (
        "train-text-hyperparameter",
        lambda r: _train(r["root"], "-n", "16", "-params", "n_steps:abc"),
        CLIError,
        "n_steps='abc' is text, but PPOLagrangian expects int",
    ),
    (
        "train-text-budget",
        lambda r: _train(r["root"], "-n", "16", "-params", "cost_budget:abc"),
        CLIError,
        "cost_budget='abc' is text",
    ),
    (
        "train-unknown-hyperparameter",
        lambda r: _train(r["root"], "-n", "16", "-params", "n_stepz:16"),
        CLIError,
        "unexpected keyword argument 'n_stepz'",
    ),
    (
        "train-hyperparameter-without-value",
        lambda r: _train(r["root"], "-params", "n_steps"),
        CLIError,
        "expects key:value pairs",
    ),
    (
        "train-negative-budget",
        lambda r: _train(r["root"], "-n", "16", "-params", "cost_budget:-1"),
        CLIError,
        "`cost_budget` must be >= 0",
    ),
    (
        "train-log-folder-is-a-file",
        lambda r: _train(r["root"], "-n", "16", "-f", r["file"]),
        CLIError,
        "a_file' is a file, not a folder",
    ),
    (
        "train-log-folder-cannot-be-made",
        lambda r: _train(r["root"], "-n", "16", "-f", f"{r['file']}/logs"),
        CLIError,
        "a_file/logs' cannot be created",
    ),
    (
        "train-tensorboard-folder-is-a-file",
        lambda r: _train(r["root"], "-n", "16", "-tb", r["file"]),
        CLIError,
        "-tb/--tensorboard-log",
    ),
    (
        "train-eval-episodes",
        lambda r: _train(r["root"], "-n", "16", "--eval-episodes", "0"),
        CLIError,
        "argument --eval-episodes: expected an integer > 0",
    ),
    (
        "train-unknown-env",
        lambda r: _train(r["root"], "-n", "16", "--env", "GridWorldWal-v0"),
        CLIError,
        "Did you mean 'GridWorldWall-v0'",
    ),
    (
        "train-unknown-algo",
        lambda r: run_cli(train_module.main, ["--algo", "sac", "--env", "GridWorldWall-v0"]),
        CLIError,
        "Unknown algo 'sac': use one of ppo, ppolag, gacl, bc2l, mecl, vicrl, irlplus, irlplusppo, or register your own",
    ),
    (
        "train-env-kwarg-value",
        lambda r: run_cli(
            train_module.main,
            [
                "--algo",
                "ppolag",
                "--env",
                "BlockedHalfCheetah-v0",
                "-f",
                f"{r['root']}/scratch",
                "-n",
                "16",
                "--env-kwargs",
                "cost_threshold:float('nan')",
            ],
        ),
        CLIError,
        "`cost_threshold` must be a finite float",
    ),
    (
        "train-unknown-env-kwarg",
        lambda r: _train(r["root"], "-n", "16", "--env-kwargs", "bogus:1"),
        CLIError,
        "unexpected keyword argument 'bogus'",
    ),
    (
        "train-missing-agent",
        lambda r: _train(r["root"], "-n", "16", "-i", f"{r['root']}/none.zip"),
        CLIError,
        "does not exist",
    ),
    (
        "train-agent-is-a-run-folder",
        lambda r: _train(r["root"], "-n", "16", "-i", r["run0"]),
        CLIError,
        "is a folder (models in it: GridWorldWall-v0.zip",
    ),
    (
        "train-agent-is-a-folder",
        lambda r: _train(r["root"], "-n", "16", "-i", r["root"]),
        CLIError,
        "is a folder: expected a model .zip file saved by stable-baselines3, such as a run's <EnvName>.zip or one of",
    ),
    (
        "train-agent-of-another-algo",
        lambda r: _train_icrl(r["root"], "-i", f"{r['run0']}/GridWorldWall-v0.zip"),
        CLIError,
        "holds a ppolag model, not a mecl one",
    ),
    (
        "train-demonstrations-for-ppolag",
        lambda r: _train(r["root"], "-n", "16", "--demonstrations", "GridWorldWall-v0"),
        CLIError,
        "are for the ICRL algorithms",
    ),
    (
        "train-allow-env-mismatch-for-ppolag",
        lambda r: _train(r["root"], "-n", "16", "--allow-env-mismatch"),
        CLIError,
        "--allow-env-mismatch accepts demonstrations recorded on another env: it is for the ICRL algorithms (gacl,",
    ),
    (
        "train-noise-model-without-noise",
        lambda r: _train(r["root"], "-n", "16", "--transition-noise-model", "shared"),
        CLIError,
        "--transition-noise-model shared says how the next-state noise of --transition-noise is drawn, and there is none",
    ),
    (
        "train-demonstrations-of-another-env",
        lambda r: _train_icrl(r["root"], "--demonstrations", "GridWorldSquare-v0"),
        CLIError,
        "recorded on 'sb3_icrl/GridWorldSquare-v0'",
    ),
    (
        "train-missing-conf",
        lambda r: _train(r["root"], "-n", "16", "-conf", f"{r['root']}/none.yml"),
        CLIError,
        "No hyper-parameter file",
    ),
    (
        "train-gym-package",
        lambda r: _train(r["root"], "-n", "16", "--gym-packages", "no_such_module_xyz"),
        CLIError,
        "cannot import 'no_such_module_xyz'",
    ),
    (
        "train-device",
        lambda r: _train(r["root"], "-n", "16", "--device", "tpu9"),
        CLIError,
        "--device 'tpu9' is not a torch device",
    ),
    ("train-negative-exp-id", lambda r: _train(r["root"], "-n", "16", "--exp-id", "-1"), CLIError, "--exp-id must be >= 0"),
    ("train-resume-without-exp-id", lambda r: _train(r["root"], "-n", "16", "--resume"), CLIError, "pass --exp-id N as well"),
    (
        "train-text-save-freq",
        lambda r: _train(r["root"], "--save-freq", "often"),
        CLIError,
        "argument --save-freq: invalid int",
    ),
    # ---------------------------------------------------------------- enjoy
    (
        "enjoy-zero-steps",
        lambda r: _enjoy("--run", r["run0"], "-n", "0"),
        CLIError,
        "argument -n/--n-timesteps: expected an integer > 0",
    ),
    (
        "enjoy-negative-seed",
        lambda r: _enjoy("--run", r["run0"], "--seed", "-1"),
        CLIError,
        "argument --seed: expected an integer >= 0",
    ),
    ("enjoy-missing-run", lambda r: _enjoy("--run", f"{r['root']}/none"), CLIError, "No run folder"),
    (
        "enjoy-missing-checkpoint",
        lambda r: _enjoy("--run", r["run0"], "--load-checkpoint", "123"),
        CLIError,
        "No rl_model_123_steps.zip",
    ),
    ("enjoy-missing-best", lambda r: _enjoy("--run", r["run0"], "--load-best"), CLIError, "No best_model.zip"),
    (
        "enjoy-other-algo",
        lambda r: run_cli(
            enjoy_module.main, ["--algo", "mecl", "--env", "GridWorldWall-v0", "--run", r["run0"], "--no-render"]
        ),
        CLIError,
        "use --algo ppolag",
    ),
    ("enjoy-no-runs", lambda r: _enjoy("-f", f"{r['root']}/empty"), CLIError, "No ppolag run of GridWorldWall-v0"),
    # ---------------------------------------------------------------- compare
    (
        "compare-reference",
        lambda r: run_cli(compare_module.main, [r["run0"], r["run1"], "--reference", "vicrl"]),
        CLIError,
        "--reference 'vicrl' has no run among the runs given (ppolag)",
    ),
    (
        "compare-zero-steps",
        lambda r: run_cli(compare_module.main, [r["run0"], "-n", "0"]),
        CLIError,
        "expected an integer > 0",
    ),
    (
        "compare-negative-seed",
        lambda r: run_cli(compare_module.main, [r["run0"], "--seed", "-1"]),
        CLIError,
        "expected an integer >= 0",
    ),
    ("compare-not-a-run", lambda r: run_cli(compare_module.main, [r["root"]]), CLIError, "is not a train.py run folder"),
    (
        "compare-same-seed",
        lambda r: run_cli(compare_module.main, [r["run0"], r["run0"]]),
        CLIError,
        "Two ppolag runs trained with seed 0",
    ),
    (
        "compare-json-under-a-file",
        lambda r: run_cli(compare_module.main, [r["run0"], "--json", f"{r['file']}/x.json"]),
        CLIError,
        "a_file/x.json' cannot be written",
    ),
    # ---------------------------------------------------------------- benchmark and plots
    (
        "benchmark-unknown-suite",
        lambda r: run_cli(benchmark_cli.main, ["run", "nosuch", "-f", r["root"]]),
        CLIError,
        "No shipped suite 'nosuch'",
    ),
    (
        "benchmark-jobs",
        lambda r: run_cli(benchmark_cli.main, ["run", "smoke", "-f", r["root"], "--jobs", "0"]),
        CLIError,
        "--jobs must be >= 1",
    ),
    (
        "benchmark-only-form",
        lambda r: run_cli(benchmark_cli.main, ["run", "smoke", "-f", r["root"], "--only", "vicrl"]),
        CLIError,
        "--only takes key=value",
    ),
    (
        "benchmark-only-key",
        lambda r: run_cli(benchmark_cli.main, ["run", "smoke", "-f", r["root"], "--only", "colour=red"]),
        CLIError,
        "not colour",
    ),
    (
        "benchmark-suite-file",
        lambda r: run_cli(benchmark_cli.main, ["run", _write(f"{r['root']}/suite.yml", "runs: 3\n"), "-f", r["root"]]),
        CLIError,
        "unknown key 'runs'; a suite has",
    ),
    (
        "benchmark-log-folder-is-a-file",
        lambda r: run_cli(benchmark_cli.main, ["run", "smoke", "-f", r["file"]]),
        CLIError,
        "a_file' is a file, not a folder",
    ),
    (
        "benchmark-report-without-runs",
        lambda r: run_cli(benchmark_cli.main, ["report", "smoke", "-f", f"{r['root']}/empty"]),
        CLIError,
        "No finished run of suite 'smoke'",
    ),
    (
        "plots-curves-without-runs",
        lambda r: run_cli(
            plots_cli.main,
            ["curves", "-f", r["root"], "--algos", "mecl", "--env", "GridWorldWall-v0", "-o", f"{r['root']}/c.png"],
        ),
        CLIError,
        "No runs of 'mecl'",
    ),
    (
        "plots-constraint-not-a-run",
        lambda r: run_cli(plots_cli.main, ["constraint", r["root"], "-o", f"{r['root']}/c.png"]),
        CLIError,
        "is not a train.py run folder",
    ),
]


@pytest.mark.parametrize(
    ("call", "error", "fragment"), [case[1:] for case in BAD_INPUTS], ids=[case[0] for case in BAD_INPUTS]
)
def test_bad_input_gets_a_clear_error(
    runs: dict[str, str], call: Callable[[dict[str, str]], Any], error: type[BaseException], fragment: str
) -> None:
    with pytest.raises(error) as raised:
        call(runs)
    assert fragment in str(raised.value)


def test_bad_inputs_ids_are_unique() -> None:
    ids = [case[0] for case in BAD_INPUTS]
    assert len(ids) == len(set(ids))


# -------------------------------------------------------------------- loading another algorithm's model


@pytest.fixture(scope="module")
def saved_models(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """A zip of each algorithm (and of SB3's PPO, and of an MECL saved before zips named their algorithm)."""
    folder = tmp_path_factory.mktemp("models")
    paths = {}
    for algorithm in ALGORITHMS:
        paths[algorithm.__name__] = str(folder / f"{algorithm.__name__}.zip")
        algorithm("MlpPolicy", GRID, **TINY).save(paths[algorithm.__name__])
    paths["PPO"] = str(folder / "PPO.zip")
    PPO("MlpPolicy", GRID, n_steps=16, batch_size=16, policy_kwargs={"net_arch": [4]}).save(paths["PPO"])
    unnamed = MECL("MlpPolicy", GRID, **TINY)
    del unnamed.sb3_icrl_algorithm  # as saved before the name was recorded: told by its trainer class
    paths["old MECL"] = str(folder / "old_MECL.zip")
    unnamed.save(paths["old MECL"])
    return paths


@pytest.mark.parametrize("loader", ALGORITHMS, ids=lambda algorithm: algorithm.__name__)
@pytest.mark.parametrize("saver", ALGORITHMS, ids=lambda algorithm: algorithm.__name__)
def test_load_refuses_another_algorithms_model(saved_models: dict[str, str], loader: type[Any], saver: type[Any]) -> None:
    path = saved_models[saver.__name__]
    if loader is saver:
        assert type(loader.load(path, device="cpu")) is loader
        return
    message = f"holds a {saver.__name__} model, not a {loader.__name__} one: load it with {saver.__name__}.load"
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(".", r"\.")):
        loader.load(path, device="cpu")


@pytest.mark.parametrize("loader", ALGORITHMS, ids=lambda algorithm: algorithm.__name__)
def test_load_refuses_a_plain_sb3_model(saved_models: dict[str, str], loader: type[Any]) -> None:
    with pytest.raises(ValueError, match=f"was not saved by an sb3-icrl algorithm .* so {loader.__name__}.load cannot"):
        loader.load(saved_models["PPO"], device="cpu")


def test_load_tells_an_older_zip_by_its_trainer(saved_models: dict[str, str]) -> None:
    assert type(MECL.load(saved_models["old MECL"], device="cpu")) is MECL
    with pytest.raises(ValueError, match="holds a MECL model, not a VICRL one"):
        VICRL.load(saved_models["old MECL"], device="cpu")


def test_load_accepts_a_users_subclass_and_a_file_object(saved_models: dict[str, str]) -> None:
    class MyVICRL(VICRL):
        pass

    assert type(MyVICRL.load(saved_models["VICRL"], device="cpu")) is MyVICRL
    with open(saved_models["PPOLagrangian"], "rb") as file:
        assert type(PPOLagrangian.load(file, device="cpu")) is PPOLagrangian
    assert issubclass(VICRL, LagrangianICRL)


def test_one_checked_load_names_a_users_algorithm() -> None:
    # The algorithms share CheckedLoadMixin's load; the mixin is never the algorithm a user's class is
    class MyICRL(ICRLAlgorithmMixin, PPO):
        pass

    assert all(algorithm.load.__func__ is CheckedLoadMixin.load.__func__ for algorithm in (*ALGORITHMS, SACLagrangian))
    assert library_algorithm(MyICRL) == "MyICRL"


# -------------------------------------------------------------------- demonstrations of another env


def test_demonstrations_of_another_env_can_be_allowed(tmp_path: pathlib.Path) -> None:
    with pytest.raises(DemonstrationError, match="recorded on 'sb3_icrl/GridWorldSquare-v0'"):
        load_demonstrations("GridWorldSquare-v0", env=gym.make(GRID))
    demos = load_demonstrations("GridWorldSquare-v0", env=GRID, allow_env_mismatch=True)
    model = MECL("MlpPolicy", GRID, **TINY)
    with pytest.raises(DemonstrationError, match="allow_env_mismatch=True"):
        model.set_demonstrations(demos)
    model.set_demonstrations(demos, allow_env_mismatch=True)
    assert model.demonstrations is demos
    # The env's own data, and data without an env id, are taken as they are
    model.set_demonstrations("GridWorldWall-v0")
    model.set_demonstrations(Demonstrations(list(demos), metadata=None))
    # The constructor's switch is saved with the model, so load() reloads such data too
    allowed = VICRL("MlpPolicy", GRID, demonstrations="GridWorldSquare-v0", allow_env_mismatch=True, **TINY)
    assert allowed.demonstrations is not None and allowed.demonstrations.metadata["env_id"] == "sb3_icrl/GridWorldSquare-v0"
    allowed.save(tmp_path / "allowed.zip")
    assert VICRL.load(tmp_path / "allowed.zip", env=gym.make(GRID), device="cpu").demonstrations is not None


def test_train_allows_demonstrations_of_another_env_on_request(runs: dict[str, str], tmp_path: pathlib.Path) -> None:
    argv = ["--algo", "mecl", "--env", "GridWorldWall-v0", "-f", str(tmp_path), "-n", "16", *TRAIN_TINY]
    with pytest.raises(CLIError, match="--allow-env-mismatch"):
        run_cli(train_module.main, [*argv, "--demonstrations", "GridWorldSquare-v0"])
    run_cli(train_module.main, [*argv, "--demonstrations", "GridWorldSquare-v0", "--allow-env-mismatch"])
    assert (tmp_path / "mecl" / "GridWorldWall-v0_1" / FINISHED_FILE).is_file()


# -------------------------------------------------------------------- failed runs


def test_a_failed_run_is_marked_and_has_no_final_model(
    runs: dict[str, str], tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def fail(*args: Any, **kwargs: Any) -> None:
        raise RuntimeError("the env broke")

    monkeypatch.setattr(PPOLagrangian, "learn", fail)
    argv = ["--algo", "ppolag", "--env", "GridWorldWall-v0", "-n", "32", "--seed", "3", "-f", str(tmp_path), "--exp-id", "3"]
    with pytest.raises(RuntimeError, match="the env broke"):
        train_module.main(argv + TRAIN_TINY)
    run = tmp_path / "ppolag" / "GridWorldWall-v0_3"
    assert json.loads((run / FAILED_FILE).read_text()) == {"error": "RuntimeError: the env broke", "num_timesteps": 0}
    assert not (run / "GridWorldWall-v0.zip").exists() and not (run / FINISHED_FILE).exists()
    with pytest.raises(CLIError, match=r"failed \(RuntimeError: the env broke\), so it has no final model"):
        _enjoy("--run", str(run))
    with pytest.raises(CLIError, match=r"failed \(RuntimeError: the env broke\): finish it with train.py --resume"):
        run_cli(compare_module.main, [runs["run0"], str(run)])
    with pytest.raises(CLIError, match=r"failed \(RuntimeError: the env broke\), so it has no final model: use --model best"):
        run_cli(data_cli.main, ["generate", "--run", str(run), "--n", "1", "--out", str(tmp_path / "demos.npz")])

    monkeypatch.undo()
    # Resumed (no checkpoint: afresh in the same folder), it finishes and is no longer marked failed
    run_cli(train_module.main, [*argv, "--resume", *TRAIN_TINY])
    assert (run / FINISHED_FILE).is_file() and (run / "GridWorldWall-v0.zip").is_file()
    assert not (run / FAILED_FILE).exists()


# -------------------------------------------------------------------- compare: checks first, Wilcoxon warning


def test_compare_checks_the_reference_before_evaluating(runs: dict[str, str], monkeypatch: pytest.MonkeyPatch) -> None:
    def never(*args: Any, **kwargs: Any) -> None:
        raise AssertionError("evaluated before the arguments were checked")

    monkeypatch.setattr(compare_module, "evaluate_run", never)
    with pytest.raises(CLIError, match="--reference 'mecl' has no run"):
        run_cli(compare_module.main, [runs["run0"], runs["run1"], "--reference", "mecl"])
    with pytest.raises(CLIError, match="--json"):
        run_cli(compare_module.main, [runs["run0"], "--json", os.path.join(runs["root"], "no_folder", "x.json")])


def test_one_wilcoxon_pair_is_flagged() -> None:
    def result(algo: str, seed: int, feasible: float) -> RunResult:
        return RunResult(f"logs/{algo}/Env_{seed}", algo, "Env-v0", seed, 100, 1.0, 0.0, feasible, feasible, 10)

    one_pair = summarise([result("mecl", 0, 10.0), result("vicrl", 0, 12.0)], reference="vicrl")
    assert one_pair["mecl"]["wilcoxon_p"] == 1.0  # what scipy gives for one pair, whatever the difference
    (warning,) = wilcoxon_warnings(one_pair, "vicrl")
    assert "mecl vs vicrl: 1 seed pair(s)" in warning and "at least 6" in warning
    five = [result(algo, seed, 10.0 + seed * (algo == "mecl")) for algo in ("mecl", "vicrl") for seed in range(1, 6)]
    assert "smallest p with 5 is 0.0625" in wilcoxon_warnings(summarise(five, "vicrl"), "vicrl")[0]
    six = [result(algo, seed, 10.0 + seed * (algo == "mecl")) for algo in ("mecl", "vicrl") for seed in range(1, 7)]
    assert wilcoxon_warnings(summarise(six, "vicrl"), "vicrl") == []


def test_compare_warns_on_one_wilcoxon_pair(runs: dict[str, str], tmp_path: pathlib.Path) -> None:
    argv = ["--algo", "ppo", "--env", "GridWorldWall-v0", "-n", "32", "--seed", "0", "-f", str(tmp_path)]
    run_cli(train_module.main, argv + TRAIN_TINY)
    stderr = io.StringIO()
    with contextlib.redirect_stderr(stderr), contextlib.redirect_stdout(io.StringIO()):
        status = compare_module.main(
            [runs["run0"], str(tmp_path / "ppo" / "GridWorldWall-v0_1"), "-n", "60", "--reference", "ppo"]
        )
    assert status == 0
    warning = stderr.getvalue()
    assert "warning: ppolag vs ppo: 1 seed pair(s)" in warning and "a two-sided Wilcoxon test needs at least 6" in warning
