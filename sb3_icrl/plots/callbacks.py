"""TensorBoard constraint figures during training."""

import warnings
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import Figure as LoggedFigure
from stable_baselines3.common.logger import TensorBoardOutputFormat

from sb3_icrl.plots.figures import (
    TrueConstraint,
    constraint_features,
    grid_constraint_figure,
    grid_cost_map,
    partial_dependence_figure,
)

#: Output formats a figure must not go to (only TensorBoard shows images)
NOT_TENSORBOARD = ("stdout", "log", "json", "csv")


class ConstraintFigureCallback(BaseCallback):
    """
    Every ``eval_freq`` calls, logs the learned constraint of an ICRL model (its ``constraint_net``) to TensorBoard:

    - grid worlds: ``constraint/map``, the learned cost of each cell beside the true unsafe cells
      (see :func:`~sb3_icrl.plots.grid_constraint_figure`)
    - envs with a feature constraint (MuJoCo, driving): ``constraint/partial_dependence_<feature>``, the partial
      dependence of the learned cost on the constrained feature, averaged over the expert samples, with a histogram
      of the feature's values in the expert data and in the latest rollouts (see
      :func:`~sb3_icrl.plots.partial_dependence_figure`)

    The env and its true constraint are read from the training env's spec (or given). A run shorter than
    ``eval_freq``, or not a multiple of it, still ends with the figures of its final model, unless the last ones came
    within the final rollout (as the zoo's evaluation callback does). Nothing is drawn when the logger has no
    TensorBoard output.

    :param eval_freq: Log every ``eval_freq`` calls of the callback (per vectorised step; <= 0: never)
    :param env_id: The env id (default: the training env's spec)
    :param env_kwargs: The env's keyword arguments (default: the spec's), for the thresholds and the grid map
    :param beta_samples: For VICRL: show the spread of costs sampled from the Beta
    :param verbose: 1: say when a figure is logged, or why none is
    """

    def __init__(
        self,
        eval_freq: int = 10000,
        env_id: str | None = None,
        env_kwargs: dict[str, Any] | None = None,
        beta_samples: bool = True,
        verbose: int = 0,
    ):
        super().__init__(verbose)
        self.eval_freq = eval_freq
        self.env_id = env_id
        self.env_kwargs = env_kwargs
        self.beta_samples = beta_samples
        self.grid_env: Any = None
        self.constraints: tuple[TrueConstraint, ...] = ()
        self.n_figures = 0
        self._warned = False
        self._last_logged_at: int | None = None  # num_timesteps of the latest figures
        self._recorded_keys: list[str] = []

    def _init_callback(self) -> None:
        if getattr(self.model, "constraint_net", None) is None:
            raise ValueError(
                f"ConstraintFigureCallback plots a learned constraint: {type(self.model).__name__} has no `constraint_net` "
                "(use it with GACL, BC2L, MECL or VICRL)."
            )
        if self.env_id is None:
            spec = self.training_env.get_attr("spec", [0])[0]
            if spec is None:
                raise ValueError("The training env has no spec: pass `env_id=` to ConstraintFigureCallback.")
            self.env_id = spec.id
            if self.env_kwargs is None:
                self.env_kwargs = dict(spec.kwargs)
        kwargs = dict(self.env_kwargs or {})
        if self.model.constraint_net.discrete_obs:  # type: ignore[attr-defined]
            self.grid_env = gym.make(self.env_id, **kwargs).unwrapped
        else:
            try:
                self.constraints = constraint_features(self.env_id, kwargs)
            except ValueError as error:
                # A user's env without a declared constraint: training goes on, without figures
                warnings.warn(f"ConstraintFigureCallback logs no figure: {error}", stacklevel=2)

    def _has_tensorboard(self) -> bool:
        return any(isinstance(output, TensorBoardOutputFormat) for output in self.logger.output_formats)

    def _rollout_observations(self) -> np.ndarray | None:
        # The latest rollouts, unnormalised (the buffer holds what the policy saw)
        buffer = getattr(self.model, "rollout_buffer", None)
        if buffer is None or getattr(buffer, "observations", None) is None:
            return None
        stored = buffer.observations if buffer.full else buffer.observations[: buffer.pos]
        if len(stored) == 0:
            return None
        observations = stored.reshape(-1, stored.shape[-1])
        vec_normalize = self.model.get_vec_normalize_env()
        return np.asarray(vec_normalize.unnormalize_obs(observations)) if vec_normalize is not None else observations

    def log_figures(self) -> int:
        """
        Draw and record the figures now.

        :return: The number of figures recorded
        """
        net: Any = self.model.constraint_net  # type: ignore[attr-defined]
        step = f"{str(self.env_id).removeprefix('sb3_icrl/')} at {self.num_timesteps} steps"
        if self.grid_env is not None:
            grid = self.grid_env
            expert_obs = getattr(self.model, "expert_obs", None)
            visited_cells = None
            if expert_obs is not None:
                visited_cells = np.zeros(grid.n_states, dtype=bool)
                visited_cells[np.asarray(expert_obs, dtype=int).reshape(-1)] = True
                visited_cells = visited_cells.reshape(grid.n_rows, grid.n_cols)
            figure = grid_constraint_figure(
                grid_cost_map(net, grid), grid.unsafe_mask, grid.start_cell, grid.goal_cell, visited=visited_cells, title=step
            )
            self._record("constraint/map", figure)
            return 1
        expert_obs, expert_acts = getattr(self.model, "expert_obs", None), getattr(self.model, "expert_acts", None)
        if expert_obs is None:
            return 0
        rollout_obs = self._rollout_observations()
        for constraint in self.constraints:
            visited: dict[str, np.ndarray] = {"expert": np.asarray(expert_obs)[:, constraint.obs_index]}
            if rollout_obs is not None:
                visited["policy (latest rollouts)"] = rollout_obs[:, constraint.obs_index]
            figure = partial_dependence_figure(
                net,
                expert_obs,
                expert_acts,
                constraint.obs_index,
                constraint.threshold,
                constraint.op,
                visited,
                beta_samples=self.beta_samples,
                feature_name=constraint.name,
                title=step,
                seed=self.num_timesteps,
            )
            self._record(f"constraint/partial_dependence_{constraint.name}", figure)
        return len(self.constraints)

    def _record(self, key: str, figure: Any) -> None:
        self.logger.record(key, LoggedFigure(figure, close=True), exclude=NOT_TENSORBOARD)
        self._recorded_keys.append(key)

    def _log(self) -> int:
        if not self._has_tensorboard():
            if self.verbose >= 1 and not self._warned:
                self._warned = True
                print("ConstraintFigureCallback: the logger has no TensorBoard output (pass tensorboard_log): no figures.")
            return 0
        self._recorded_keys = []
        count = self.log_figures()
        self.n_figures += count
        self._last_logged_at = self.num_timesteps
        if self.verbose >= 1:
            print(f"ConstraintFigureCallback: {count} figure(s) logged at {self.num_timesteps} steps")
        return count

    def _on_step(self) -> bool:
        if self.eval_freq > 0 and self.n_calls % self.eval_freq == 0:
            self._log()
        return True

    def _on_training_end(self) -> None:
        # A run shorter than eval_freq (train.py's default --eval-freq is longer than the grid worlds' runs) still shows
        # its recovered constraint; a figure from within the final rollout is recent enough
        rollout = int(getattr(self.model, "n_steps", 1)) * int(self.model.n_envs)
        latest = self._last_logged_at
        if self.eval_freq <= 0 or self.n_calls == 0 or (latest is not None and self.num_timesteps - latest < rollout):
            return
        if self._log() == 0:
            return
        # No dump follows the end of training: write the figures to TensorBoard now (only there: a dump would also
        # add an empty row to the other outputs)
        values = {key: self.logger.name_to_value.pop(key) for key in self._recorded_keys}
        excluded = {key: self.logger.name_to_excluded.pop(key, NOT_TENSORBOARD) for key in self._recorded_keys}
        for key in self._recorded_keys:
            self.logger.name_to_count.pop(key, None)
        for output in self.logger.output_formats:
            if isinstance(output, TensorBoardOutputFormat):
                output.write(values, excluded, self.num_timesteps)
