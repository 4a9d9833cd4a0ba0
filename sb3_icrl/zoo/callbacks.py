"""Evaluation callback with the benchmark's metrics; model selection sees only what the learner knows."""

import contextlib
import os
import pickle
import re
import time
import warnings
from collections.abc import Callable, Sequence
from copy import deepcopy
from typing import Any

import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback, EvalCallback
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.vec_env import VecEnv, unwrap_vec_normalize

from sb3_icrl.common.evaluation import evaluate_constraint
from sb3_icrl.common.utils import (
    atomic_save_model,
    atomic_save_npz,
    atomic_save_pickle,
    atomic_save_replay_buffer,
    check_evaluation_rows,
    read_npz,
)
from sb3_icrl.run_env import LearnedCostRecorder, RecordedEpisode
from sb3_icrl.run_folder import BEST_VECNORMALIZE_FILE, CHECKPOINT_PATTERN, monitor_row_counts
from sb3_icrl.zoo.summary import evaluation_line, model_multiplier


def learned_episode_stats(
    episodes: Sequence[RecordedEpisode], cost_fn: Callable[[np.ndarray, np.ndarray], Any], threshold: float = 0.5
) -> np.ndarray:
    """
    Price recorded episodes with a learned cost.

    :param episodes: The episodes
    :param cost_fn: Learned cost per step, ``cost_fn(observations, actions) -> (T,)``
    :param threshold: A step counts as infeasible when its learned cost exceeds this
    :return: One row per episode: ``(reward, learned feasible reward, learned cost, length)``; the learned feasible
        reward sums the rewards before the first infeasible step
    """
    rows = np.zeros((len(episodes), 4))
    for row, episode in zip(rows, episodes, strict=True):
        costs = np.asarray(cost_fn(episode.observations, episode.actions), dtype=float).reshape(len(episode.rewards))
        broken = np.flatnonzero(costs > threshold)
        feasible_steps = broken[0] if len(broken) else len(costs)
        row[:] = episode.rewards.sum(), episode.rewards[:feasible_steps].sum(), costs.sum(), len(costs)
    return rows


def learned_penalised_rewards(model: Any, stats: np.ndarray) -> np.ndarray | None:
    """
    Each episode's reward less ``lambda * max(0, learned cost - budget)``, with the learner's multiplier and budget as
    they stand (a per-step budget times the episode length); ``None`` for models without a multiplier. A model that
    charges its cost signed (``signed_costs``, IRL-Plus's penalty on the reward) is priced as it trains, unfloored:
    ``lambda * (learned cost - budget)``.

    :param model: The learner (a Lagrangian one has ``lagrange_multiplier``, ``cost_budget`` and ``budget_statistic``)
    :param stats: Rows ``(reward, learned feasible reward, learned cost, length)`` of :func:`learned_episode_stats`
    """
    multiplier = getattr(model, "lagrange_multiplier", None)
    if multiplier is None:
        return None
    budget = float(np.asarray(model.cost_budget).reshape(-1)[0])
    multiplier_value = float(np.asarray(multiplier.value).reshape(-1)[0])
    rewards, costs, lengths = stats[:, 0], stats[:, 2], stats[:, 3]
    allowance = budget * lengths if model.budget_statistic == "step" else np.full_like(costs, budget)
    excess = costs - allowance
    if not getattr(model, "signed_costs", False):
        excess = np.maximum(excess, 0.0)
    return rewards - multiplier_value * excess


def learned_selection_score(model: Any, stats: np.ndarray) -> float:
    """
    The score that ranks models with a learned constraint: the mean learned penalised reward
    (:func:`learned_penalised_rewards`), or for models without a multiplier the mean learned feasible reward.

    :param model: The learner
    :param stats: Rows of :func:`learned_episode_stats`
    """
    penalised = learned_penalised_rewards(model, stats)
    return float((penalised if penalised is not None else stats[:, 1]).mean())


def rescore_episodes(
    model: Any, episodes: Sequence[RecordedEpisode], cost_fn: Callable[[np.ndarray, np.ndarray], Any]
) -> float | None:
    """
    Earlier recorded episodes (the best model's) priced again: their :func:`learned_selection_score` under ``cost_fn``
    and the model's multiplier and budget as they stand now.

    :param model: The learner now
    :param episodes: The recorded episodes (none: no best model yet)
    :param cost_fn: The learned cost now
    :return: The score, or ``None`` when there are no episodes
    """
    if not episodes:
        return None
    return learned_selection_score(model, learned_episode_stats(episodes, cost_fn))


#: The file beside ``evaluations.npz`` with the model selection's values, one per evaluation
SELECTION_FILE = "model_selection.npz"
#: Per-evaluation means that older ``evaluations.npz`` files held (1-D) -> the per-episode key that replaced each
LEARNED_EPISODE_KEYS = {
    "learned_feasible_reward": "learned_feasible_rewards",
    "mean_learned_cost": "learned_episode_costs",
    "learned_penalised_reward": "learned_penalised_rewards",
}


def _episode_row(values: np.ndarray | None, n_episodes: int) -> np.ndarray:
    """One evaluation's per-episode values as a row of ``n_episodes`` (NaN for missing ones, or for ``None``)."""
    row = np.full(n_episodes, np.nan)
    if values is not None:
        values = np.asarray(values, dtype=float).reshape(-1)[:n_episodes]
        row[: len(values)] = values
    return row


def split_evaluation_history(
    arrays: dict[str, np.ndarray], selection: dict[str, np.ndarray] | None = None
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """
    The arrays of an ``evaluations.npz`` and its ``model_selection.npz`` in the current layout (see
    :class:`ConstraintEvalCallback`), from files of any version. Older ``evaluations.npz`` files held one value per
    evaluation (1-D) for the learned metrics and the model selection: each learned mean becomes its per-episode key,
    the mean repeated for each episode of its evaluation (so per-evaluation means, all that rl_zoo3 and our plots
    read, are kept); the other 1-D arrays move to the selection values.

    :param arrays: The arrays of ``evaluations.npz``
    :param selection: The arrays of ``model_selection.npz``, if there is one
    :return: ``(evaluations, selection)``: ``timesteps`` and per-episode arrays; ``timesteps`` and 1-D arrays
    """
    timesteps = np.asarray(arrays.get("timesteps", np.zeros(0, dtype=int)))
    n_eval = len(timesteps)
    results = np.asarray(arrays.get("results", np.zeros((n_eval, 0))))
    n_episodes = results.shape[1] if results.ndim == 2 else 1
    evaluations: dict[str, np.ndarray] = {}
    moved: dict[str, np.ndarray] = {}
    for key, value in arrays.items():
        value = np.asarray(value)
        if key == "timesteps" or value.ndim != 1:
            evaluations[key] = value
        elif key in LEARNED_EPISODE_KEYS:
            evaluations[LEARNED_EPISODE_KEYS[key]] = np.repeat(value.astype(float)[:, None], n_episodes, axis=1)
        else:
            moved[key] = value
    current = dict(selection or {})
    if moved:
        current = {"timesteps": timesteps, **moved, **current}
    if current and "lagrange_multiplier" not in current:
        current["lagrange_multiplier"] = np.full(len(current["timesteps"]), np.nan)
    return evaluations, current


def _rows_up_to(arrays: dict[str, np.ndarray], up_to_timesteps: int) -> dict[str, list]:
    """The rows of the evaluations made up to ``up_to_timesteps``, as lists (of each key) to append to."""
    keep = np.asarray(arrays.get("timesteps", []), dtype=float) <= up_to_timesteps
    return {key: [row for row, kept in zip(rows, keep, strict=True) if kept] for key, rows in arrays.items()}


class ConstraintEvalCallback(EvalCallback):
    """
    rl-zoo's evaluation callback with the ICRL metrics. Each evaluation logs under ``eval/``: ``mean_reward``,
    ``feasible_reward``, ``violation_rate`` and ``mean_cost`` (true constraint, reporting only), and for models with a
    learned constraint ``learned_feasible_reward`` and ``mean_learned_cost`` (plus ``learned_penalised_reward`` when
    a Lagrangian learner holds that cost to a budget), for driving envs ``collision_rate``, ``off_road_rate``,
    ``time_out_rate`` and ``goal_reached_rate``.

    ``evaluations.npz`` keeps SB3's layout, which rl_zoo3's ``all_plots`` (``--key``) and scripts written for SB3 read:
    ``timesteps`` ``(n_eval,)`` and only per-episode arrays ``(n_eval, n_episodes)``: SB3's ``results`` and
    ``ep_lengths``, ``feasible_rewards``, ``violations``, ``episode_costs``, the driving outcome flags, and under the
    learned constraint ``learned_feasible_rewards``, ``learned_episode_costs`` and ``learned_penalised_rewards``
    (NaN where the model has none). The values with one number per evaluation (``selection_score``,
    ``best_model_rescored``, ``lagrange_multiplier``) go to ``model_selection.npz`` beside it, each ``(n_eval,)``
    with its ``timesteps``: rl_zoo3 averages every ``--key`` over a last axis of episodes, which they lack.

    The best model (``best_model.zip``) is chosen on what the learner itself knows, never the true constraint:

    - BC2L, MECL, VICRL: the learned penalised reward, each episode's reward less ``lambda`` times the learned cost
      it spent beyond the learner's own budget (``lambda`` and budget as they stand at the evaluation). The learner
      prices its learned cost this way; a cost within budget costs nothing.
    - GACL and other learned-constraint models without a multiplier: the reward summed until the learned cost first
      exceeds 0.5.
    - PPO-Lagrangian (trained on the env's cost): its feasible reward; PPO: its mean reward.

    The constraint changes during training, so at each evaluation the best model so far is priced again: its recorded
    episodes with the current learned cost, ``lambda`` and budget (logged as ``best_model_rescored``). A new model
    replaces it when it scores higher under the same constraint. A model that went where the constraint of its day
    did not yet forbid thus loses its place once the constraint learns better.

    :param eval_env: The evaluation env; wrap its bottom in :class:`LearnedCostRecorder` for the learned metrics
    :param recorder: The :class:`LearnedCostRecorder` at the bottom of ``eval_env``
    :param summary: Print one line per evaluation (step, return, true violation rate, feasible reward, multiplier)
        when ``verbose`` is 0; with ``verbose >= 1`` every metric is printed instead
    :param kwargs: :class:`~stable_baselines3.common.callbacks.EvalCallback`'s arguments
    """

    def __init__(self, eval_env: VecEnv, recorder: LearnedCostRecorder | None = None, summary: bool = False, **kwargs: Any):
        super().__init__(eval_env, **kwargs)
        self.recorder = recorder
        self.summary = summary
        self.history: dict[str, list] = {}  # evaluations.npz: timesteps and per-episode rows
        self.selection_history: dict[str, list] = {}  # model_selection.npz: one value per evaluation
        self.best_score = -np.inf
        self.best_episodes: list[RecordedEpisode] = []  # the best model's recorded episodes, priced again later
        #: Seconds spent evaluating in this process (finished.json's ``evaluation_time_s``: evaluation's share of a run)
        self.eval_seconds = 0.0

    def resume_history(self, up_to_timesteps: int) -> None:
        """
        Go on from the ``evaluations.npz`` (and ``model_selection.npz``) of an interrupted run: keep its evaluations
        made up to ``up_to_timesteps`` (the checkpoint the run resumes from), and the best selection score among them,
        so that the best model is replaced only by a better one. Files of earlier versions, with one value per
        evaluation in ``evaluations.npz``, are read too (:func:`split_evaluation_history`).

        :param up_to_timesteps: Steps of the checkpoint the run resumes from
        """
        path = self.log_path if self.log_path is None or self.log_path.endswith(".npz") else self.log_path + ".npz"
        if path is None or not os.path.isfile(path):
            return
        selection_path = os.path.join(os.path.dirname(path), SELECTION_FILE)
        try:
            arrays = read_npz(path)
            selection = read_npz(selection_path) if os.path.isfile(selection_path) else {}
            check_evaluation_rows(arrays, path)
            check_evaluation_rows(selection, selection_path)
        except ValueError as error:
            # The run goes on (a suite retries it as it is): its curves then start at the checkpoint
            warnings.warn(f"{error} The resumed run's evaluations start afresh at step {up_to_timesteps}.", stacklevel=2)
            return
        history, selection = split_evaluation_history(arrays, selection)
        self.history = _rows_up_to(history, up_to_timesteps)
        self.selection_history = _rows_up_to(selection, up_to_timesteps)
        scores = [float(score) for score in self.selection_history.get("selection_score", [])]
        if scores and os.path.isfile(os.path.join(self.best_model_save_path or "", "best_model.zip")):
            # Without the checkpoint's own state (load_state_dict), the best score as recorded
            self.best_score = max(scores)

    def state_dict(self) -> dict[str, Any]:
        """
        The model selection's state, saved with each checkpoint so that a resumed run goes on choosing as the
        interrupted one would have: the best score and the best model's recorded episodes, priced again at each
        evaluation (the evaluations themselves are in ``evaluations.npz``, see :meth:`resume_history`).

        :return: Plain numbers and numpy arrays, for :meth:`load_state_dict`
        """
        episodes = [(episode.observations, episode.actions, episode.rewards) for episode in self.best_episodes]
        return {"best_score": float(self.best_score), "best_episodes": episodes}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """
        Go on from a :meth:`state_dict` (call after :meth:`resume_history`, whose best score it replaces).

        :param state: From :meth:`state_dict`
        """
        if not {"best_score", "best_episodes"} <= set(state):
            raise ValueError("Not a ConstraintEvalCallback state: expected 'best_score' and 'best_episodes'.")
        self.best_score = float(state["best_score"])
        self.best_episodes = [RecordedEpisode(*(np.asarray(part) for part in parts)) for parts in state["best_episodes"]]

    def _init_callback(self) -> None:
        # The eval env is built like the training one, but the ICRL models add their own wrappers to theirs
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="Training and eval env are not of the same type")
            super()._init_callback()

    def _sync_normalization(self) -> None:
        # The ICRL models wrap their training env further than the eval env (nominal recorder, learned cost), so
        # SB3's ``sync_envs_normalization``, which walks both stacks in step, cannot pair them: copy the statistics
        train_normalize = self.model.get_vec_normalize_env()
        eval_normalize = unwrap_vec_normalize(self.eval_env)
        if train_normalize is None or eval_normalize is None:
            if (train_normalize is None) != (eval_normalize is None):
                raise ValueError("The training and evaluation envs must both use VecNormalize, or neither.")
            return
        eval_normalize.obs_rms = deepcopy(train_normalize.obs_rms)
        eval_normalize.ret_rms = deepcopy(train_normalize.ret_rms)

    def _on_training_end(self) -> None:
        # A run shorter than eval_freq, or not a multiple of it, still ends with an evaluation of its final model, unless
        # the last one came within the final rollout: the run's length rounds up to whole rollouts, and evaluating a
        # model that a few hundred steps changed again would only cost time
        evaluated = self.history.get("timesteps", [])
        rollout = int(getattr(self.model, "n_steps", 1)) * int(self.model.n_envs)
        if self.eval_freq > 0 and self.n_calls > 0 and (not evaluated or self.num_timesteps - evaluated[-1] >= rollout):
            eval_freq, self.eval_freq = self.eval_freq, 1
            try:
                self._on_step()
            finally:
                self.eval_freq = eval_freq

    def _selection_score(self, metrics: dict[str, float]) -> float:
        for learned_score in ("learned_penalised_reward", "learned_feasible_reward"):
            if learned_score in metrics:
                return metrics[learned_score]
        if getattr(self.model, "cost_fn", "absent") is None:  # PPO-Lagrangian on the env's own cost
            return metrics["feasible_reward"]
        return metrics["mean_reward"]

    def _on_step(self) -> bool:
        if self.eval_freq <= 0 or self.n_calls % self.eval_freq != 0:
            return True
        start = time.process_time()
        try:
            return self._evaluate()
        finally:
            self.eval_seconds += time.process_time() - start

    def _evaluate(self) -> bool:
        self._sync_normalization()
        constraint_net = getattr(self.model, "constraint_net", None)
        if self.recorder is not None:
            self.recorder.recording = constraint_net is not None
            self.recorder.clear()
        result = evaluate_constraint(
            self.model, self.eval_env, n_eval_episodes=self.n_eval_episodes, deterministic=self.deterministic
        )
        metrics = {
            "mean_reward": result.mean_reward,
            "std_reward": float(np.std(result.episode_rewards)),
            "feasible_reward": result.mean_feasible_reward,
            "violation_rate": result.violation_rate,
            "mean_cost": result.mean_cost,
            "mean_ep_length": float(np.mean(result.episode_lengths)),
            **result.outcome_rates,  # driving envs: collision, off-road, time-out and goal rates
            **result.constraint_violation_rates,  # envs with several constraints: each one's violation rate
        }
        episodes = self.recorder.counted_episodes(self.n_eval_episodes) if self.recorder is not None else []
        learned_per_episode: dict[str, np.ndarray | None] = dict.fromkeys(LEARNED_EPISODE_KEYS.values())
        if constraint_net is not None and episodes:
            learned = learned_episode_stats(episodes, constraint_net.cost)
            penalised = learned_penalised_rewards(self.model, learned)
            learned_per_episode["learned_feasible_rewards"] = learned[:, 1]
            learned_per_episode["learned_episode_costs"] = learned[:, 2]
            learned_per_episode["learned_penalised_rewards"] = penalised
            metrics["learned_feasible_reward"] = float(learned[:, 1].mean())
            metrics["mean_learned_cost"] = float(learned[:, 2].mean())
            if penalised is not None:
                metrics["learned_penalised_reward"] = float(penalised.mean())
            rescored = rescore_episodes(self.model, self.best_episodes, constraint_net.cost)
            if rescored is not None:
                self.best_score = metrics["best_model_rescored"] = rescored
        self.last_mean_reward = metrics["mean_reward"]
        for key, value in metrics.items():
            self.logger.record(f"eval/{key}", value)
        self.logger.record("time/total_timesteps", self.num_timesteps, exclude="tensorboard")
        self.logger.dump(self.num_timesteps)
        if self.verbose >= 1:
            print(f"Eval num_timesteps={self.num_timesteps}, " + ", ".join(f"{k}={v:.3g}" for k, v in metrics.items()))
        elif self.summary:
            print(evaluation_line(self.num_timesteps, metrics, model_multiplier(self.model)), flush=True)

        self.history.setdefault("timesteps", []).append(self.num_timesteps)
        self.history.setdefault("results", []).append(result.episode_rewards)
        self.history.setdefault("ep_lengths", []).append(result.episode_lengths)
        self.history.setdefault("feasible_rewards", []).append(result.feasible_rewards)
        self.history.setdefault("violations", []).append(result.violations)
        self.history.setdefault("episode_costs", []).append(result.episode_costs)
        for key, flags in result.outcomes.items():
            self.history.setdefault(key, []).append(flags)
        n_episodes = len(result.episode_rewards)
        for key, values in learned_per_episode.items():
            self.history.setdefault(key, []).append(_episode_row(values, n_episodes))
        score = self._selection_score(metrics)
        multiplier = model_multiplier(self.model)
        self.selection_history.setdefault("timesteps", []).append(self.num_timesteps)
        self.selection_history.setdefault("selection_score", []).append(score)
        self.selection_history.setdefault("best_model_rescored", []).append(metrics.get("best_model_rescored", np.nan))
        self.selection_history.setdefault("lagrange_multiplier", []).append(np.nan if multiplier is None else multiplier)
        if self.log_path is not None:
            atomic_save_npz(self.log_path, {key: np.array(value) for key, value in self.history.items()})
            selection_path = os.path.join(os.path.dirname(self.log_path), SELECTION_FILE)
            atomic_save_npz(selection_path, {key: np.array(value) for key, value in self.selection_history.items()})

        if score > self.best_score:
            self.best_score = score
            self.best_episodes = episodes
            if self.verbose >= 1:
                print(f"New best model (selection score {score:.3g})")
            if self.best_model_save_path is not None:
                atomic_save_model(self.model, os.path.join(self.best_model_save_path, "best_model"))
                # Its statistics as they are now: the final ones would run it on differently scaled observations
                vec_normalize = self.model.get_vec_normalize_env()
                if vec_normalize is not None:
                    atomic_save_pickle(vec_normalize, os.path.join(self.best_model_save_path, BEST_VECNORMALIZE_FILE))
            if self.callback_on_new_best is not None:
                return self.callback_on_new_best.on_step()
        return True


#: Version of the training-state files (:func:`save_training_state`)
TRAINING_STATE_FORMAT = 1


def training_state_path(model_path: str, name: str) -> str:
    """
    Where the training state of a saved model goes: ``<prefix>_training_state_<steps>_steps.pkl`` beside a checkpoint
    ``<prefix>_<steps>_steps.zip``, else ``<EnvName>/training_state.pkl`` in the model's folder (the final model).

    :param model_path: The model zip
    :param name: The env name (folder name of the run's parameters)
    """
    folder, base = os.path.split(os.path.abspath(model_path))
    match = CHECKPOINT_PATTERN.match(base)
    if match:
        return os.path.join(folder, f"{match['prefix']}_training_state_{match['steps']}_steps.pkl")
    return os.path.join(folder, name, "training_state.pkl")


class WallClock:
    """
    The wall time and the CPU time (of the training process) a run has taken to reach where it is, across resumed
    segments: the times saved with the checkpoint it resumed from (the offsets) plus this segment's. Work lost after a
    run's last checkpoint is not counted.

    :param offset: Wall seconds taken before this segment
    :param cpu_offset: CPU seconds taken before this segment (``None``: not recorded by the checkpoint, so that the
        whole run's CPU time is unknown)
    """

    def __init__(self, offset: float = 0.0, cpu_offset: float | None = 0.0):
        self.offset = float(offset)
        self.cpu_offset = None if cpu_offset is None else float(cpu_offset)
        self.start = time.time()
        self.cpu_start = time.process_time()

    def segment_elapsed(self) -> float:
        """Wall seconds of this segment."""
        return time.time() - self.start

    def segment_cpu_elapsed(self) -> float:
        """CPU seconds of this segment."""
        return time.process_time() - self.cpu_start

    def elapsed(self) -> float:
        """Wall seconds so far, earlier segments included."""
        return self.offset + self.segment_elapsed()

    def cpu_elapsed(self) -> float | None:
        """CPU seconds so far, earlier segments included (``None`` when an earlier segment's are unknown)."""
        if self.cpu_offset is None:
            return None
        return self.cpu_offset + self.segment_cpu_elapsed()


def save_training_state(
    model: Any,
    path: str,
    evaluation: ConstraintEvalCallback | None = None,
    wall_time_s: float | None = None,
    monitor_rows: dict[str, int] | None = None,
    cpu_time_s: float | None = None,
) -> None:
    """
    Save, atomically, what a resumed run needs beyond the model zip: the ICRL trainer's state
    (:meth:`~sb3_icrl.icrl.ICRLTrainer.state_dict`: nominal memory, unused trajectories, last update step, sampler)
    and the model selection's (:meth:`ConstraintEvalCallback.state_dict`). Write it before the model it goes with.

    :param model: The learner (an ICRL model has ``icrl_trainer``)
    :param path: Destination (:func:`training_state_path`)
    :param evaluation: The run's evaluation callback, if any
    :param wall_time_s: The run's wall time so far (:class:`WallClock`), for the resumed run to count on from
    :param monitor_rows: Episodes in each Monitor file of the run so far
        (:func:`~sb3_icrl.run_folder.monitor_row_counts`), for the resumed run to drop those recorded after this point
    :param cpu_time_s: The run's CPU time so far (:meth:`WallClock.cpu_elapsed`), for the resumed run to count on from
    """
    trainer = getattr(model, "icrl_trainer", None)
    state = {
        "format": TRAINING_STATE_FORMAT,
        "num_timesteps": int(model.num_timesteps),
        "icrl_trainer": trainer.state_dict() if trainer is not None else None,
        "evaluation": evaluation.state_dict() if evaluation is not None else None,
        "wall_time_s": wall_time_s,
        "monitor_rows": monitor_rows,
        "cpu_time_s": cpu_time_s,
    }
    atomic_save_pickle(state, path)


def _saved_state(path: str) -> dict[str, Any]:
    """A :func:`save_training_state` file's content (empty when the file is missing or holds no mapping)."""
    if not os.path.isfile(path):
        return {}
    state = _unpickle_state(path)
    return state if isinstance(state, dict) else {}


def _unpickle_state(path: str) -> Any:
    """A training state file's content; a file cut short is named (pickle's own error names no file)."""
    try:
        with open(path, "rb") as file:
            return pickle.load(file)  # as trusted as the VecNormalize pickles beside it
    except (pickle.UnpicklingError, EOFError) as error:
        raise ValueError(
            f"The training state {path} cannot be read ({type(error).__name__}: {error}): it is cut short or damaged; "
            "continue from another checkpoint of the run, or delete the file to continue without it (the ICRL trainer "
            "and the model selection then start afresh)."
        ) from error


def training_state_wall_time(path: str) -> float:
    """
    The run's wall time saved in a :func:`save_training_state` file (0 when the file or the value is missing).

    :param path: The state file
    :return: Seconds
    """
    value = _saved_state(path).get("wall_time_s")
    return float(value) if value is not None else 0.0


def training_state_cpu_time(path: str) -> float | None:
    """
    The run's CPU time saved in a :func:`save_training_state` file (``None`` when the file or the value is missing:
    a checkpoint of an earlier version, whose run's CPU time before it is unknown).

    :param path: The state file
    :return: Seconds
    """
    value = _saved_state(path).get("cpu_time_s")
    return float(value) if value is not None else None


def training_state_monitor_rows(path: str) -> dict[str, int] | None:
    """
    The episodes per Monitor file saved in a :func:`save_training_state` file (``None``: a file of an earlier
    version, or none).

    :param path: The state file
    """
    rows = _saved_state(path).get("monitor_rows")
    return dict(rows) if isinstance(rows, dict) else None


def load_training_state(model: Any, path: str, evaluation: ConstraintEvalCallback | None = None) -> bool:
    """
    Restore a :func:`save_training_state` file into ``model`` (its ICRL trainer, built here if it has none yet) and
    ``evaluation``. A state saved at another step count than the model's is not used, with a warning.

    :param model: The learner, loaded from the model the state was saved with
    :param path: The state file (:func:`training_state_path`)
    :param evaluation: The evaluation callback to restore (``None``: leave the model selection to start afresh)
    :return: Whether a state was restored (``False``: no file)
    """
    if not os.path.isfile(path):
        return False
    state = _unpickle_state(path)
    if not isinstance(state, dict) or state.get("format") != TRAINING_STATE_FORMAT:
        raise ValueError(
            f"{path} is not a training state of this sb3-icrl version (format {TRAINING_STATE_FORMAT}): it was overwritten, "
            "or written by another version; continue from another checkpoint of the run, or delete the file to continue "
            "without it (the ICRL trainer and the model selection then start afresh)."
        )
    if state["num_timesteps"] != model.num_timesteps:
        warnings.warn(
            f"{path} was saved at {state['num_timesteps']} steps, the model at {model.num_timesteps}: not used (the ICRL "
            "trainer and the model selection start afresh)."
        )
        return False
    if state["icrl_trainer"] is not None and hasattr(model, "icrl_trainer"):
        if model.icrl_trainer is None or model.icrl_trainer.recorder is not model.recorder:
            model.icrl_trainer = model._make_trainer()  # the trainer learn() would build, so that it keeps this one
        model.icrl_trainer.load_state_dict(state["icrl_trainer"])
    if evaluation is not None and state["evaluation"] is not None:
        evaluation.load_state_dict(state["evaluation"])
    return True


def has_replay_buffer(model: Any) -> bool:
    """
    :param model: The learner
    :return: Whether it learns from a replay buffer (an off-policy algorithm: SAC, SAC-Lagrangian, IRL-Plus)
    """
    return isinstance(model, OffPolicyAlgorithm) and model.replay_buffer is not None


def replay_buffer_path(model_path: str, num_timesteps: int) -> str:
    """
    Where the replay buffer saved with a model is: ``<prefix>_replay_buffer_<steps>_steps.pkl`` beside a checkpoint
    ``<prefix>_<steps>_steps.zip`` (the name SB3's ``CheckpointCallback`` gives it), else, for another model (the final
    one, saved without its buffer), the buffer of the run's checkpoint at the model's step count beside it
    (``rl_model_replay_buffer_<num_timesteps>_steps.pkl``): a run that ended on a checkpoint saved it there.

    :param model_path: The model zip
    :param num_timesteps: The model's step count
    """
    folder, base = os.path.split(os.path.abspath(model_path))
    match = CHECKPOINT_PATTERN.match(base)
    prefix = match["prefix"] if match else "rl_model"
    return os.path.join(folder, f"{prefix}_replay_buffer_{num_timesteps}_steps.pkl")


def load_replay_buffer(model: OffPolicyAlgorithm, path: str) -> bool:
    """
    Restore the replay buffer saved at a checkpoint (:class:`AtomicCheckpointCallback`) into ``model``: its
    transitions, position and fill go on as they were.

    :param model: The learner, loaded from the model the buffer was saved with
    :param path: The buffer file (:func:`replay_buffer_path`)
    :return: Whether a buffer was restored (``False``: no file; the model keeps its empty buffer)
    :raises ValueError: When the file is cut short, damaged or holds no replay buffer, or the path is a folder (naming
        it)
    """
    if not os.path.exists(path):
        return False
    if not os.path.isfile(path):  # (SB3 would go on without a word, as if no buffer had been saved)
        what = "a folder" if os.path.isdir(path) else "not a regular file"
        raise ValueError(
            f"The replay buffer {path} is {what}, not a replay buffer file: remove it to continue from its checkpoint "
            "with an empty replay buffer, or continue from another checkpoint."
        )
    previous = model.replay_buffer
    try:
        model.load_replay_buffer(path)  # as trusted as the VecNormalize pickles beside it
        if not isinstance(model.replay_buffer, ReplayBuffer):  # SB3 asserts it, which python -O skips
            raise TypeError(f"it holds a {type(model.replay_buffer).__name__}")
    except (MemoryError, OSError):
        model.replay_buffer = previous
        raise  # not the content's fault (an OSError names the file)
    except Exception as error:
        model.replay_buffer = previous
        # A damaged pickle fails in many ways (truncated, a key or a type that does not fit...), none naming the file
        raise ValueError(
            f"The replay buffer {path} cannot be read ({type(error).__name__}: {error}): it is cut short or damaged; "
            "delete it to continue from its checkpoint with an empty replay buffer, or continue from another checkpoint."
        ) from error
    return True


class ReplayBufferRefill(BaseCallback):
    """
    Hold back an off-policy learner's gradient updates until its replay buffer holds ``learning_starts`` transitions
    again. A run continued from a checkpoint without its buffer (or with fewer transitions) would otherwise update at
    once, SB3 counting ``learning_starts`` against the total steps, on the few transitions collected since.

    It sets the model's ``gradient_steps`` to 0 from the end of each rollout to the start of the next (the only span in
    which SB3 reads it), rather than moving ``learning_starts``: the learner keeps acting with its policy (not the
    random actions of SB3's warm-up), and each checkpoint saves the model's own settings. Put it first among the
    callbacks, so that it restores them before a checkpoint is written.

    :param updates_after: The updates resume once the model's ``num_timesteps`` is past this step count
    :param verbose: Verbosity level
    """

    def __init__(self, updates_after: int, verbose: int = 0):
        super().__init__(verbose)
        self.updates_after = int(updates_after)
        self._gradient_steps: int | None = None

    @classmethod
    def for_model(cls, model: BaseAlgorithm) -> "ReplayBufferRefill | None":
        """
        :param model: A learner continued from a checkpoint, its replay buffer restored (or left empty)
        :return: The callback that holds back its updates, ``None`` when its buffer holds enough transitions (or SB3's
            own ``learning_starts`` holds them back as long)
        """
        if not isinstance(model, OffPolicyAlgorithm) or model.replay_buffer is None:
            return None
        buffer = model.replay_buffer
        # size() counts rows of n_envs transitions; a buffer smaller than learning_starts is refilled to its capacity
        wanted = min(model.learning_starts, buffer.buffer_size * buffer.n_envs)
        missing = wanted - buffer.size() * buffer.n_envs
        updates_after = model.num_timesteps + missing
        if missing <= 0 or updates_after <= model.learning_starts:
            return None
        return cls(updates_after)

    def _on_rollout_end(self) -> None:
        assert isinstance(self.model, OffPolicyAlgorithm)
        if self.model.num_timesteps <= self.updates_after and self._gradient_steps is None:
            self._gradient_steps = self.model.gradient_steps
            self.model.gradient_steps = 0

    def _on_rollout_start(self) -> None:
        self.release()

    def _on_training_end(self) -> None:
        self.release()

    def release(self) -> None:
        """Give the model back its ``gradient_steps`` (a run stopped between a rollout and the next saves it too)."""
        if self._gradient_steps is not None:
            assert isinstance(self.model, OffPolicyAlgorithm)
            self.model.gradient_steps = self._gradient_steps
            self._gradient_steps = None

    def _on_step(self) -> bool:
        return True


class AtomicCheckpointCallback(CheckpointCallback):
    """
    Checkpoints (model, ``VecNormalize`` statistics, training state and an off-policy learner's replay buffer) every
    ``save_freq`` timesteps, taken where a run can be continued exactly: at the start of a rollout, after the previous
    update, so a resumed run (``train.py --resume`` or ``-i``) collects the same rollouts the interrupted one had left.
    Each file is written atomically, the model last: a run killed at any moment leaves whole checkpoints only, each
    with its statistics and state beside it.

    A replay buffer holds up to ``buffer_size`` transitions (hundreds of MB for a million MuJoCo steps), so only the
    newest checkpoint keeps one: once a checkpoint's model is written, every other replay buffer of the folder is
    removed (while it is written, the folder holds two). An older checkpoint resumes with an empty buffer.

    :param save_freq: Timesteps between checkpoints (the first rollout start at or past each multiple)
    :param save_path: Folder of the checkpoints
    :param name_prefix: File prefix: ``<prefix>_<timesteps>_steps.zip``
    :param save_replay_buffer: Also save the replay buffer of an off-policy model
        (``<prefix>_replay_buffer_<timesteps>_steps.pkl``, SB3's ``save_replay_buffer`` pickle; the newest only)
    :param save_vecnormalize: Also save the ``VecNormalize`` statistics (``<prefix>_vecnormalize_<timesteps>_steps.pkl``)
    :param save_training_state: Also save the training state (``<prefix>_training_state_<timesteps>_steps.pkl``,
        see :func:`save_training_state`)
    :param evaluation: The run's evaluation callback, whose model selection goes into the training state
    :param wall_clock: The run's wall clock, whose time so far goes into the training state
    :param verbose: Verbosity level
    """

    def __init__(
        self,
        save_freq: int,
        save_path: str,
        name_prefix: str = "rl_model",
        save_replay_buffer: bool = False,
        save_vecnormalize: bool = False,
        save_training_state: bool = False,
        evaluation: ConstraintEvalCallback | None = None,
        wall_clock: WallClock | None = None,
        verbose: int = 0,
    ):
        super().__init__(
            save_freq,
            save_path,
            name_prefix=name_prefix,
            save_replay_buffer=save_replay_buffer,
            save_vecnormalize=save_vecnormalize,
            verbose=verbose,
        )
        self.save_training_state = save_training_state
        self.evaluation = evaluation
        self.wall_clock = wall_clock
        self._last_saved = 0

    def _init_callback(self) -> None:
        super()._init_callback()
        # A resumed run counts from its checkpoint. The model's count, not the callback's: the callback's is set at its
        # first step, so before it a resumed run would save at once over the checkpoint it started from
        self._last_saved = self.model.num_timesteps

    def _on_rollout_start(self) -> None:
        if self.num_timesteps - self._last_saved < self.save_freq:
            return
        self._last_saved = self.num_timesteps
        buffer_path = None
        if self.save_replay_buffer and has_replay_buffer(self.model):
            buffer_path = self._checkpoint_path("replay_buffer_", extension="pkl")
            atomic_save_replay_buffer(self.model, buffer_path)
        vec_normalize = self.model.get_vec_normalize_env()
        if self.save_vecnormalize and vec_normalize is not None:
            atomic_save_pickle(vec_normalize, self._checkpoint_path("vecnormalize_", extension="pkl"))
        if self.save_training_state:
            clock = self.wall_clock
            path = self._checkpoint_path("training_state_", extension="pkl")
            rows = monitor_row_counts(self.save_path)
            save_training_state(
                self.model,
                path,
                self.evaluation,
                wall_time_s=clock.elapsed() if clock is not None else None,
                monitor_rows=rows,
                cpu_time_s=clock.cpu_elapsed() if clock is not None else None,
            )
        model_path = atomic_save_model(self.model, self._checkpoint_path(extension="zip"))
        if buffer_path is not None:
            # Only now: a run killed before its model was written resumes from the previous checkpoint, with its buffer
            self._remove_other_replay_buffers(buffer_path)
        if self.verbose >= 2:
            print(f"Saving model checkpoint to {model_path}")

    def _remove_other_replay_buffers(self, keep: str) -> None:
        """
        Delete the folder's replay buffers but ``keep``: those of older checkpoints, and one whose model a kill left
        unwritten (whatever its step count: it belongs to no checkpoint of this run any more). Only regular files go: a
        folder (or link) with a buffer's name is not one this callback wrote, and ``os.remove`` would fail on a folder.

        :param keep: The replay buffer just written
        """
        pattern = re.compile(rf"^{re.escape(self.name_prefix)}_replay_buffer_\d+_steps\.pkl$")
        with os.scandir(self.save_path) as entries:
            stale = [
                entry.path
                for entry in entries
                if pattern.match(entry.name) and entry.path != keep and entry.is_file(follow_symlinks=False)
            ]
        for path in stale:
            with contextlib.suppress(FileNotFoundError):
                os.remove(path)

    def _on_training_end(self) -> None:
        self._on_rollout_start()  # the end of training is a rollout boundary too

    def _on_step(self) -> bool:
        return True
