"""
Does a learned constraint transfer? A fresh PPO-Lagrangian is trained from scratch on the frozen learned cost of a
finished ICRL run (budget and budget statistic as the run ended) on one of three tasks, beside two references trained
the same way (same hyper-parameters, ``zoo_hyperparams/ppolag.yml``): PPO-Lagrangian on the true cost (the
**oracle**) and unconstrained PPO::

    sb3-icrl transfer logs/mecl/BlockedHalfCheetah-v0_1 --task reward -n 200000 --seed 0

- ``same``: the env the constraint was learned on (with the run's transition noise);
- ``reward``: a task whose reward pulls toward the constrained side (:data:`~sb3_icrl.envs.REWARD_TRANSFER_TASKS`,
  e.g. ``BlockedHalfCheetahBackward-v0``), same observations and true constraint;
- ``dynamics``: the env with transition noise :data:`DYNAMICS_NOISE` (:class:`~sb3_icrl.envs.TransitionNoiseWrapper`).

The learner reads only the learned cost: its env is wrapped in a
:class:`~sb3_icrl.constraints.wrappers.LearnedCostVecEnvWrapper`, which moves the true cost out of ``info["cost"]``.
Each model is then evaluated on held-out episodes against the true cost (violation rate, feasible reward), and the
results go into ``<run>/transfer_<task>.json`` (written atomically).

The two references do not depend on the run (they never read its constraint), so each is trained once per task, seed
and setting and kept in ``<folder>/transfer_references/`` (``--references-dir``): the transfers of every run under
one log folder share them. Runs that reach the same references at once (two queues on one seed) split them through a
lock file beside each: one trains the oracle while the other trains PPO, and each reads the other's when it is saved.
"""

import argparse
import copy
import hashlib
import inspect
import json
import os
import pathlib
import re
import sys
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback

from sb3_icrl import __version__
from sb3_icrl.common.evaluation import evaluate_constraint
from sb3_icrl.common.utils import atomic_write_json, file_lock, plain_docstring
from sb3_icrl.constraints.wrappers import LearnedCostVecEnvWrapper
from sb3_icrl.envs import NAMESPACE, REWARD_TRANSFER_TASKS
from sb3_icrl.envs.wrappers import COMPONENT_NOISE, TransitionNoiseWrapper, recorded_transition_noise
from sb3_icrl.hyperparams import algo_kwargs, load_hyperparams, preprocess_hyperparams
from sb3_icrl.metrics.identification import _load_run_policy, read_icrl_run, run_demonstration_pairs, run_model_path
from sb3_icrl.ppo_lagrangian import PPOLagrangian
from sb3_icrl.registry import import_gym_packages, resolve_env_id

#: The transfer tasks
TASKS = ("same", "reward", "dynamics")
#: Transition noise of the ``dynamics`` task
DYNAMICS_NOISE = 1e-2
#: The two references of a transfer: PPO-Lagrangian on the true cost and unconstrained PPO
REFERENCE_LEARNERS = ("oracle", "ppo")
#: The learners of a transfer: the frozen learned cost first, then the references
LEARNERS = ("learned", *REFERENCE_LEARNERS)
#: Bumped when the results change meaning
TRANSFER_VERSION = 1
#: The folder of shared references beside a log folder's algorithm folders (``<folder>/transfer_references``)
REFERENCES_FOLDER = "transfer_references"
#: Exit status of ``sb3-icrl transfer --no-wait`` when the references it lacks are all being trained by other runs
#: (EX_TEMPFAIL: try again later; the learned-cost result is kept in the partial file)
DEFERRED_EXIT = 75
#: How the suite runner heads each command it appends to a run's log (``=== <time> <command>``), so that readers of
#: the log tell one command's output from the next
LOG_COMMAND_PREFIX = "=== "
#: What a reference learner depends on, of a transfer's settings (never the run's constraint, model or budget)
REFERENCE_SETTINGS = ("version", "env", "env_kwargs", "transition_noise", "n_timesteps", "seed", "eval_episodes", "eval_seed")
#: The line a transfer test logs as a learner starts training, and one of the ten it logs as it goes (read back by
#: :func:`transfer_progress`)
TRAINING_LINE = "transfer ({task}) on {env}: training {learner} for {steps} steps"
PROGRESS_LINE = "  {learner}: {steps}/{total} steps, {speed:.0f} steps/s"
#: The line a transfer test logs while it waits for a reference another run trains
WAITING_LINE = "transfer ({task}) on {env}: waiting for {learner}, which another run is training ({file})"
_TRAINING_PATTERN = re.compile(r"transfer \((\w+)\) on \S+: training (\w+) for (\d+) steps")
_PROGRESS_PATTERN = re.compile(r"  (\w+): (\d+)/(\d+) steps, (\d+) steps/s")
_WAITING_PATTERN = re.compile(r"transfer \((\w+)\) on \S+: waiting for (\w+), .*")
#: Any other line of a transfer test (a learner reused, ...): no learner trains after it until the next training line
_OTHER_TRANSFER_PATTERN = re.compile(r"transfer \(\w+\) on \S+: .*")
#: How much of the end of a run's log :func:`transfer_progress` reads (a test logs a few lines per learner)
PROGRESS_TAIL_BYTES = 1 << 16


def transfer_file(task: str) -> str:
    """
    :param task: One of :data:`TASKS`
    :return: The name of the task's result file in a run folder
    """
    return f"transfer_{task}.json"


def partial_transfer_file(task: str) -> str:
    """
    :param task: One of :data:`TASKS`
    :return: The name of the file that keeps a task's learned-cost result while its references are still to come (a
        transfer cut then, at a suite's deadline, keeps its longest learner); gone once the result file is written
    """
    return f"transfer_{task}.partial.json"


def transfer_env(env_id: str, task: str, transition_noise: float = 0.0) -> tuple[str, float]:
    """
    The env and transition noise of a transfer task.

    :param env_id: The env the constraint was learned on
    :param task: One of :data:`TASKS`
    :param transition_noise: The noise the constraint was learned with (kept by ``same``)
    :return: ``(env id, transition noise)``
    """
    if task not in TASKS:
        raise ValueError(f"Unknown transfer task {task!r}: choose one of {', '.join(TASKS)}.")
    if task == "same":
        return env_id, transition_noise
    if task == "dynamics":
        return env_id, DYNAMICS_NOISE
    name = env_id.split("/", 1)[1] if env_id.startswith(f"{NAMESPACE}/") else env_id
    if name not in REWARD_TRANSFER_TASKS:
        raise ValueError(
            f"{env_id} has no reward-transfer task; envs with one: {', '.join(sorted(REWARD_TRANSFER_TASKS))}. "
            "Use --task same or --task dynamics."
        )
    return f"{NAMESPACE}/{REWARD_TRANSFER_TASKS[name]}", transition_noise


def _wrapper_class(params: dict[str, Any], transition_noise: float, noise_model: str) -> Any:
    """The yml's env wrappers under the task's transition noise, as ``train.py`` wraps its envs."""
    wrappers = list(params.get("env_wrapper") or [])
    if not wrappers and transition_noise <= 0:
        return None

    def wrap(env: Any) -> Any:
        if transition_noise > 0:
            env = TransitionNoiseWrapper(env, sigma=transition_noise, model=noise_model)
        for wrapper, kwargs in wrappers:
            env = wrapper(env, **kwargs)
        return env

    return wrap


def _ppo_kwargs(kwargs: dict[str, Any]) -> dict[str, Any]:
    """The PPO-Lagrangian keyword arguments that plain PPO takes too (the cost critic's own settings dropped)."""
    from stable_baselines3 import PPO

    accepted = set(inspect.signature(PPO.__init__).parameters)
    kept = {key: value for key, value in kwargs.items() if key in accepted}
    if isinstance(kept.get("policy_kwargs"), dict):
        kept["policy_kwargs"] = {key: value for key, value in kept["policy_kwargs"].items() if not key.startswith("cost_")}
    return kept


class ProgressLines(BaseCallback):
    """
    One line per tenth of a learner's training steps, with its speed: progress a log file can show.

    :param name: The learner's name, at the start of each line
    :param total_timesteps: Its training steps
    :param log: Where the lines go
    """

    def __init__(self, name: str, total_timesteps: int, log: Any):
        super().__init__()
        self.name, self.total_timesteps, self.log = name, total_timesteps, log
        self.every = max(1, total_timesteps // 10)
        self.next_line = self.every
        self.start = time.time()

    def _on_step(self) -> bool:
        if self.num_timesteps >= self.next_line:
            speed = self.num_timesteps / max(time.time() - self.start, 1e-9)
            self.log(
                PROGRESS_LINE.format(learner=self.name, steps=self.num_timesteps, total=self.total_timesteps, speed=speed)
            )
            self.next_line = (self.num_timesteps // self.every + 1) * self.every  # one line even when a step spans several
        return True


def train_learner(
    learner: str,
    env_id: str,
    env_kwargs: dict[str, Any],
    transition_noise: float,
    params: dict[str, Any],
    n_timesteps: int,
    seed: int,
    cost_fn: Any = None,
    budget: float | None = None,
    budget_statistic: str | None = None,
    log: Any = None,
    transition_noise_model: str = "component",
) -> tuple[Any, Any]:
    """
    Train one learner of a transfer from scratch.

    :param learner: ``"learned"`` (PPO-Lagrangian on ``cost_fn``), ``"oracle"`` (PPO-Lagrangian on the true cost) or
        ``"ppo"`` (unconstrained)
    :param env_id: The task's env
    :param env_kwargs: Its keyword arguments
    :param transition_noise: Its transition noise
    :param params: Preprocessed PPO-Lagrangian hyper-parameters (:func:`~sb3_icrl.hyperparams.preprocess_hyperparams`)
    :param n_timesteps: Training steps
    :param seed: Seed
    :param cost_fn: The frozen learned cost (``learned`` only)
    :param budget: The learned cost's budget (``learned`` only)
    :param budget_statistic: Its statistic, ``"step"`` or ``"episode"`` (``learned`` only)
    :param log: Where a progress line goes every tenth of the steps (none when ``None``)
    :param transition_noise_model: How the transition noise is drawn (see
        :class:`~sb3_icrl.envs.wrappers.TransitionNoiseWrapper`)
    :return: The model and its training env (``VecNormalize`` statistics inside, when normalising)
    """
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    if learner not in LEARNERS:
        raise ValueError(f"Unknown learner {learner!r}: choose one of {', '.join(LEARNERS)}.")
    venv: Any = make_vec_env(
        env_id,
        n_envs=params["n_envs"],
        seed=seed,
        env_kwargs=env_kwargs,
        wrapper_class=_wrapper_class(params, transition_noise, transition_noise_model),
        vec_env_cls=DummyVecEnv,
    )
    kwargs = algo_kwargs(params)
    kwargs.pop("policy", None)
    if learner == "learned":
        if cost_fn is None or budget is None:
            raise ValueError("The 'learned' learner needs the learned cost_fn and its budget.")
        # The learner reads the learned cost in info["cost"]; the true one is moved away, for evaluation only
        venv = LearnedCostVecEnvWrapper(venv, cost_fn)
        kwargs.update(cost_budget=float(budget), budget_statistic=budget_statistic or kwargs.get("budget_statistic", "step"))
    if params["normalize"]:
        venv = VecNormalize(venv, **dict(params.get("normalize_kwargs") or {}))
    if learner == "ppo":
        model: Any = PPO(params["policy"], venv, seed=seed, verbose=0, **_ppo_kwargs(kwargs))
    else:
        model = PPOLagrangian(params["policy"], venv, seed=seed, verbose=0, **kwargs)
    model.learn(n_timesteps, callback=None if log is None else ProgressLines(learner, n_timesteps, log))
    return model, venv


def evaluate_learner(
    model: Any,
    train_env: Any,
    env_id: str,
    env_kwargs: dict[str, Any],
    transition_noise: float,
    params: dict[str, Any],
    n_episodes: int,
    eval_seed: int,
    transition_noise_model: str = "component",
) -> dict[str, float]:
    """
    Held-out episodes of a trained learner against the true cost (``info["cost"]`` of the raw task env), under the
    transition noise it trained with (``transition_noise`` drawn by ``transition_noise_model``).

    :return: ``violation_rate``, ``feasible_reward``, ``reward``, ``mean_cost``, ``n_episodes``
    """
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    venv: Any = make_vec_env(
        env_id,
        n_envs=1,
        seed=eval_seed,
        env_kwargs=env_kwargs,
        wrapper_class=_wrapper_class(params, transition_noise, transition_noise_model),
        vec_env_cls=DummyVecEnv,
    )
    if isinstance(train_env, VecNormalize):
        venv = VecNormalize(venv, training=False, norm_reward=False, norm_obs=train_env.norm_obs)
        venv.obs_rms, venv.clip_obs = copy.deepcopy(train_env.obs_rms), train_env.clip_obs
    evaluation = evaluate_constraint(model, venv, n_episodes, seed=eval_seed)
    venv.close()
    return {
        "violation_rate": evaluation.violation_rate,
        "feasible_reward": evaluation.mean_feasible_reward,
        "reward": evaluation.mean_reward,
        "mean_cost": evaluation.mean_cost,
        "n_episodes": len(evaluation.violations),
    }


def feasible_reward_ratio(learned: float, oracle: float) -> float:
    """
    The learned-cost learner's feasible reward as a share of the oracle's.

    :return: ``learned / oracle``; ``nan`` when the oracle's feasible reward is not positive (no scale to compare to)
    """
    return float(learned / oracle) if oracle > 0 else float("nan")


def default_references_dir(run_folder: str | os.PathLike) -> pathlib.Path:
    """
    Where a run's transfer tests keep the shared references unless told otherwise (``--references-dir``).

    :param run_folder: The run folder ``<folder>/<algo>/<EnvName>_<N>``
    :return: ``<folder>/transfer_references``, shared by every run of the log folder
    """
    return pathlib.Path(run_folder).resolve().parent.parent / REFERENCES_FOLDER


def reference_file(references_dir: str | os.PathLike, learner: str, settings: dict[str, Any]) -> pathlib.Path:
    """
    Where a reference learner's result is kept: one file per learner and settings.

    :param references_dir: The folder of shared references
    :param learner: ``"oracle"`` or ``"ppo"``
    :param settings: Everything its training and evaluation depend on (JSON-serialisable)
    :return: ``<references_dir>/<learner>_<EnvName>_<digest>.json``
    """
    digest = hashlib.sha256(json.dumps(_as_json(settings), sort_keys=True).encode()).hexdigest()[:16]
    return pathlib.Path(references_dir) / f"{learner}_{str(settings['env']).split('/')[-1]}_{digest}.json"


def _as_json(value: dict[str, Any]) -> dict[str, Any]:
    """``value`` as it reads back from a JSON file (tuples as lists, other objects as strings), to compare settings."""
    return json.loads(json.dumps(value, sort_keys=True, default=str))


def _cached_reference(path: pathlib.Path, settings: dict[str, Any], log: Any) -> dict[str, float] | None:
    """A reference's saved result when it was made with exactly ``settings``, else ``None``."""
    if not path.is_file():
        return None
    with open(path) as file:
        saved = json.load(file)
    if saved.get("settings") != _as_json(settings):
        return None
    if saved.get("sb3_icrl_version") != __version__:
        log(f"  {path.name} was made by sb3-icrl {saved.get('sb3_icrl_version')}: --retrain-references to train it again")
    return saved["result"]


def learned_cost_budget(icrl_model: Any, args: dict[str, Any]) -> tuple[float, str]:
    """
    The budget the learned-cost learner keeps: the run's own budget and statistic as it ended. GACL's policy keeps no
    budget (its discriminator corrects the reward instead), so its learner gets the expert's mean learned cost per step
    over the run's demonstrations, what the other methods' ``cost_budget="expert"`` sets: as feasible as the expert
    under the learned constraint, read from the demonstrations only.

    An off-policy run's budget on its cost critic (``"critic"``: a discounted cost-to-go) becomes the per-step budget
    it amounts to, ``budget * (1 - cost_gamma)``: the transfer's learner is PPO-Lagrangian.

    :param icrl_model: The run's model
    :param args: The run's saved arguments (``args.yml``)
    :return: ``(budget, budget statistic)``
    """
    if hasattr(icrl_model, "cost_budget"):
        budget = float(np.asarray(icrl_model.cost_budget).reshape(-1)[0])
        statistic = str(getattr(icrl_model, "budget_statistic", "step"))
        if statistic == "critic":
            return budget * (1.0 - float(icrl_model.cost_gamma)), "step"
        return budget, statistic
    return float(np.mean(icrl_model.constraint_cost(*run_demonstration_pairs(args)))), "step"


def transfer_cost_fn(icrl_model: Any) -> Any:
    """
    The learned cost the transfer's constrained learner keeps within its budget: the run's ``constraint_cost`` floored
    at 0. A constrained learner counts violations; IRL-Plus's cost, charged as a penalty on the reward, dips below 0,
    and a cost below 0 would let the learner bank credit to spend past the line (the other methods' costs, ``1 - phi``,
    are never below 0: for them the floor changes nothing).

    :param icrl_model: The run's model
    :return: ``cost_fn(observations, actions) -> costs >= 0``
    """

    def cost_fn(observations: np.ndarray, actions: np.ndarray) -> np.ndarray:
        return np.maximum(icrl_model.constraint_cost(observations, actions), np.float32(0))

    return cost_fn


class ReferencesBusyError(RuntimeError):
    """The references a transfer lacks are all being trained by other runs, and it was told not to wait for them."""


def run_transfer(
    run_folder: str | os.PathLike,
    task: str,
    n_timesteps: int | None = None,
    seed: int = 0,
    eval_episodes: int = 10,
    eval_seed: int = 100,
    references: bool = True,
    model: str = "final",
    log: Any = print,
    references_dir: str | os.PathLike | None = None,
    retrain_references: bool = False,
    wait: bool = True,
) -> dict[str, Any]:
    """
    Train the learned-cost learner (and the references) on a transfer task, evaluate them and write
    ``<run>/transfer_<task>.json``.

    :param run_folder: A finished ICRL run folder ``<folder>/<algo>/<EnvName>_<N>``
    :param task: One of :data:`TASKS`
    :param n_timesteps: Training steps of each learner (default: the ``ppolag.yml`` entry's)
    :param seed: Seed of the learners
    :param eval_episodes: Held-out episodes per learner
    :param eval_seed: Seed of the held-out episodes
    :param references: Also train the oracle and unconstrained PPO
    :param model: The run's model whose constraint is frozen: ``"final"``, ``"best"`` or a path
    :param log: Where progress lines go
    :param references_dir: Where the references are kept and looked up (default: ``transfer_references`` beside the
        run's algorithm folder, shared by every run of the log folder)
    :param retrain_references: Train the references even when a saved result with the same settings exists
    :param wait: When every reference still missing is being trained by another run, wait for them; ``False``: raise
        :class:`ReferencesBusyError` instead (the learned-cost result stays in the partial file, so the same call later
        only reads the references), leaving the core to other work meanwhile
    :return: The JSON written
    :raises ReferencesBusyError: See ``wait``
    """
    run, args = read_icrl_run(run_folder)
    if n_timesteps is not None and n_timesteps < 1:
        raise ValueError(f"-n/--n-timesteps must be >= 1, got {n_timesteps}.")
    if eval_episodes < 1:
        raise ValueError(f"--eval-episodes must be >= 1, got {eval_episodes}.")
    source_env = resolve_env_id(args["env"])
    env_kwargs = dict(args.get("env_kwargs") or {})
    recorded_noise, noise_model = recorded_transition_noise(args)
    env_id, noise = transfer_env(source_env, task, recorded_noise)
    icrl_model, _, _ = _load_run_policy(run, model)
    model_file = run_model_path(run, args, model)
    budget, budget_statistic = learned_cost_budget(icrl_model, args)
    entry, key = load_hyperparams("ppolag", source_env)  # the source robot's recipe, for all three learners
    params = preprocess_hyperparams(entry)
    steps = int(n_timesteps) if n_timesteps is not None else params["n_timesteps"]
    shared_dir = pathlib.Path(references_dir) if references_dir is not None else default_references_dir(run)
    settings: dict[str, Any] = _as_json(
        {
            "version": TRANSFER_VERSION,
            "task": task,
            "env": env_id,
            "source_env": source_env,
            "env_kwargs": env_kwargs,
            "transition_noise": noise,
            "n_timesteps": steps,
            "seed": seed,
            "eval_episodes": eval_episodes,
            "eval_seed": eval_seed,
            "model": model,
            "budget": budget,
            "budget_statistic": budget_statistic,
            "hyperparams": f"ppolag.yml:{key}",
            "ppolag_hyperparams": entry,
            # Named only when not the default, so that results saved before noise had a model keep their settings
            **({"transition_noise_model": noise_model} if noise_model != COMPONENT_NOISE else {}),
        }
    )
    reusable = _reusable_learned(run, task, model_file, settings)

    def train_and_evaluate(learner: str) -> dict[str, float]:
        start = time.time()
        log(TRAINING_LINE.format(task=task, env=env_id, learner=learner, steps=steps))
        trained, train_env = train_learner(
            learner,
            env_id,
            env_kwargs,
            noise,
            params,
            steps,
            seed,
            cost_fn=transfer_cost_fn(icrl_model) if learner == "learned" else None,
            budget=budget,
            budget_statistic=budget_statistic,
            log=log,
            transition_noise_model=noise_model,
        )
        result = evaluate_learner(
            trained, train_env, env_id, env_kwargs, noise, params, eval_episodes, eval_seed, transition_noise_model=noise_model
        )
        result["wall_time_min"] = (time.time() - start) / 60.0
        train_env.close()
        return result

    learners = LEARNERS if references else ("learned",)
    reference_learners = [learner for learner in learners if learner in REFERENCE_LEARNERS]
    results: dict[str, dict[str, float]] = {}
    if reusable is not None:
        # The same transfer was run before (perhaps without the references, or cut before them): its learned-cost
        # learner is kept
        log(f"transfer ({task}) on {env_id}: learned reused from {reusable[0]}")
        results["learned"] = reusable[1]
    else:
        results["learned"] = train_and_evaluate("learned")
        if reference_learners:
            atomic_write_json(run / partial_transfer_file(task), {"settings": settings, "results": results}, indent=2)

    # The references are shared by every run of their env, seed and settings. Runs that reach them at once (two queues
    # on the same seed) split them, each training one that nobody else is training, instead of both training both
    pending: dict[str, tuple[pathlib.Path, dict[str, Any]]] = {}
    reference_files: dict[str, str] = {}
    for learner in reference_learners:
        reference_settings = _as_json(
            {
                **{name: settings[name] for name in (*REFERENCE_SETTINGS, "transition_noise_model") if name in settings},
                "learner": learner,
                "hyperparams": entry,
            }
        )
        pending[learner] = (reference_file(shared_dir, learner, reference_settings), reference_settings)
        reference_files[learner] = str(pending[learner][0])
    if pending:
        shared_dir.mkdir(parents=True, exist_ok=True)
    while pending:
        taken_any = False
        for learner, (cache, reference_settings) in list(pending.items()):
            with file_lock(cache.with_suffix(".lock")) as taken:
                if not taken:
                    continue
                taken_any = True
                cached = None if retrain_references else _cached_reference(cache, reference_settings, log)
                if cached is not None:
                    log(f"transfer ({task}) on {env_id}: {learner} reused from {cache}")
                    results[learner] = cached
                else:
                    results[learner] = train_and_evaluate(learner)
                    saved = {"settings": reference_settings, "result": results[learner], "sb3_icrl_version": __version__}
                    atomic_write_json(cache, saved, indent=2)
                del pending[learner]
        if pending and not taken_any:
            # Another run is training every reference still missing: wait for the first, then read what it saved
            learner, (cache, _) = next(iter(pending.items()))
            if not wait:
                raise ReferencesBusyError(
                    f"transfer ({task}) on {env_id}: {', '.join(pending)} being trained by another run ({cache}): "
                    "deferred, its learned-cost result kept for the next try"
                )
            log(WAITING_LINE.format(task=task, env=env_id, learner=learner, file=cache))
            with file_lock(cache.with_suffix(".lock"), blocking=True):
                pass
    results = {learner: results[learner] for learner in learners}
    summary: dict[str, Any] = {
        "settings": {**settings, "reference_files": reference_files},
        "results": results,
        "violation_rate": results["learned"]["violation_rate"],
        "feasible_reward_ratio": (
            feasible_reward_ratio(results["learned"]["feasible_reward"], results["oracle"]["feasible_reward"])
            if "oracle" in results
            else float("nan")
        ),
    }
    atomic_write_json(run / transfer_file(task), summary, indent=2)
    (run / partial_transfer_file(task)).unlink(missing_ok=True)
    return summary


def _reusable_learned(
    run: pathlib.Path, task: str, model_file: str | os.PathLike, settings: dict[str, Any]
) -> tuple[pathlib.Path, dict[str, float]] | None:
    """
    The learned-cost result an earlier transfer of the run saved with the same ``settings``: in its result file, else
    in the partial file of one cut before its references were done. Neither counts when older than the run's model (a
    run continued in place since has another learned cost).

    :return: ``(file, result)``, or ``None`` when there is none to reuse
    """
    for name in (transfer_file(task), partial_transfer_file(task)):
        path = run / name
        if not path.is_file() or os.path.getmtime(path) < os.path.getmtime(model_file):
            continue
        with open(path) as file:
            saved = json.load(file)
        saved_settings = {key: value for key, value in saved.get("settings", {}).items() if key != "reference_files"}
        if saved_settings == settings and "learned" in saved.get("results", {}):
            return path, saved["results"]["learned"]
    return None


def read_transfers(run_folder: str | os.PathLike) -> dict[str, dict[str, Any]]:
    """
    The transfer results saved in a run folder.

    :param run_folder: A run folder
    :return: ``{task: transfer JSON}`` for each task run so far
    """
    found = {}
    for task in TASKS:
        path = pathlib.Path(run_folder) / transfer_file(task)
        if path.is_file():
            with open(path) as file:
                found[task] = json.load(file)
    return found


def transfer_times(transfers: Iterable[dict[str, Any]]) -> tuple[float | None, dict[str, float]]:
    """
    The compute of a run's saved transfers (its ``transfer_<task>.json`` files, one per task).

    :param transfers: The saved JSONs
    :return: The seconds their learned-cost learners trained (``None`` when none was saved with its time), and per
        reference file they read (by file name: runs of one env and seed share them), the seconds that reference's
        learner trained
    """
    learned: float | None = None
    references: dict[str, float] = {}
    for transfer in transfers:
        results = transfer.get("results", {})
        minutes = results.get("learned", {}).get("wall_time_min")
        if minutes is not None:
            learned = (learned or 0.0) + 60 * float(minutes)
        for learner, path in transfer.get("settings", {}).get("reference_files", {}).items():
            if results.get(learner, {}).get("wall_time_min") is not None:
                references[os.path.basename(path)] = 60 * float(results[learner]["wall_time_min"])
    return learned, references


def transfer_spent_seconds(times: Iterable[tuple[float | None, Mapping[str, float]]]) -> float:
    """
    What transfer tests cost together: every run's learned-cost learners, and each reference learner once, however
    many runs read its file (runs of one env and seed share them).

    :param times: Per run, what :func:`transfer_times` returns: its learned-cost learners' seconds (``None``: not
        timed) and its reference files' seconds by file name
    :return: The seconds
    """
    learned = 0.0
    references: dict[str, float] = {}
    for run_learned, run_references in times:
        learned += run_learned or 0.0
        references.update(run_references)
    return learned + sum(references.values())


@dataclass
class TransferProgress:
    """
    Where a transfer test under way stands, as its log shows it.

    :param task: Its task
    :param learner: The learner training now (one of :data:`LEARNERS`), or the reference it waits for
    :param steps: Its steps so far (at the last of its ten progress lines)
    :param total: Its training steps (0 while waiting)
    :param steps_per_s: Its speed so far (``None`` before its first progress line)
    :param waiting: The test waits for ``learner``, a reference another run is training
    """

    task: str
    learner: str
    steps: int
    total: int
    steps_per_s: float | None = None
    waiting: bool = False


def transfer_progress(log_file: str | os.PathLike) -> TransferProgress | None:
    """
    The learner a run's transfer test is training, read from the end of the run's log (the engine appends each
    command's output to it, after a ``===`` line naming the command).

    :param log_file: The run's log
    :return: The learner's progress (or the reference it waits for); ``None`` when the log is missing, or its last
        command is not a transfer test or trains no learner now (it reuses one)
    """
    try:
        with open(log_file, "rb") as file:
            file.seek(max(0, os.fstat(file.fileno()).st_size - PROGRESS_TAIL_BYTES))
            lines = file.read().decode(errors="replace").splitlines()
    except OSError:
        return None
    progress = None
    for line in lines:
        if line.startswith(LOG_COMMAND_PREFIX):  # a command starts: a test's progress ends with it
            progress = None
        elif match := _TRAINING_PATTERN.fullmatch(line):
            progress = TransferProgress(match[1], match[2], 0, int(match[3]))
        elif match := _WAITING_PATTERN.fullmatch(line):
            progress = TransferProgress(match[1], match[2], 0, 0, waiting=True)
        elif _OTHER_TRANSFER_PATTERN.fullmatch(line):
            progress = None
        elif progress is not None and (match := _PROGRESS_PATTERN.fullmatch(line)) and match[1] == progress.learner:
            progress.steps, progress.steps_per_s = int(match[2]), float(match[4])
    return progress


def get_parser(prog: str | None = None) -> argparse.ArgumentParser:
    """The parser of ``sb3-icrl transfer``."""
    parser = argparse.ArgumentParser(
        prog=prog, description=plain_docstring(__doc__), formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("run", help="A finished ICRL run folder <folder>/<algo>/<EnvName>_<N>")
    parser.add_argument("--task", required=True, choices=TASKS, help="same env, reward toward the constraint, noisy dynamics")
    parser.add_argument(
        "-n", "--n-timesteps", type=int, default=None, help="Training steps per learner (default: ppolag.yml's)"
    )
    parser.add_argument("--seed", type=int, default=0, help="Seed of the learners")
    parser.add_argument("--eval-episodes", type=int, default=10, help="Held-out episodes per learner")
    parser.add_argument("--eval-seed", type=int, default=100, help="Seed of the held-out episodes")
    parser.add_argument("--model", default="final", help="'final', 'best' or a path: whose constraint is frozen")
    parser.add_argument("--no-references", action="store_true", help="Train only the learned-cost learner")
    parser.add_argument(
        "--references-dir",
        default=None,
        help="Where the oracle and PPO references are kept and reused (default: transfer_references in the log folder)",
    )
    parser.add_argument(
        "--retrain-references", action="store_true", help="Train the references even when saved ones match the settings"
    )
    parser.add_argument(
        "--no-wait",
        action="store_true",
        help=f"Exit with status {DEFERRED_EXIT} instead of waiting when other runs are training every reference still "
        "missing (the learned-cost result is kept: running the same command later only reads the references)",
    )
    parser.add_argument("--num-threads", type=int, default=1, help="Torch threads (default 1)")
    parser.add_argument(
        "--gym-packages",
        nargs="+",
        default=[],
        help="Modules to import first: they register your own envs (those recorded in the run's args.yml are imported too)",
    )
    return parser


def main(argv: Sequence[str] | None = None, prog: str | None = None) -> int:
    """
    ``sb3-icrl transfer``.

    :param argv: Arguments (default: ``sys.argv[1:]``)
    :param prog: Program name in the usage line
    :return: Exit status: 0, 2 after a clear error, or :data:`DEFERRED_EXIT` (``--no-wait``)
    """
    args = get_parser(prog).parse_args(argv)
    th.set_num_threads(max(1, args.num_threads))
    try:
        import_gym_packages(args.gym_packages)
        summary = run_transfer(
            args.run,
            args.task,
            n_timesteps=args.n_timesteps,
            seed=args.seed,
            eval_episodes=args.eval_episodes,
            eval_seed=args.eval_seed,
            references=not args.no_references,
            model=args.model,
            references_dir=args.references_dir,
            retrain_references=args.retrain_references,
            log=partial(print, flush=True),  # progress shows in a log file as it happens
            wait=not args.no_wait,
        )
    except ReferencesBusyError as error:
        print(error, flush=True)
        return DEFERRED_EXIT
    except (FileNotFoundError, ValueError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    for learner, result in summary["results"].items():
        print(
            f"{learner:>8}: violation rate {result['violation_rate']:.0%}, feasible reward {result['feasible_reward']:.1f}, "
            f"reward {result['reward']:.1f} ({result['n_episodes']} episodes)"
        )
    print(f"feasible reward / oracle's: {summary['feasible_reward_ratio']:.2f}")
    print(f"Saved {os.path.join(args.run, transfer_file(args.task))}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
