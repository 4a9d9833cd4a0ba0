"""
The ICRL alternation as an SB3 callback: every ``update_every`` policy steps, take the learner's recent trajectories
as nominal data, update the constraint model on expert vs nominal pairs, install it in the env wrapper, log.
"""

from abc import abstractmethod
from typing import Any, ClassVar, NamedTuple

import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback

from sb3_icrl.constraints.networks import _ConstraintNet
from sb3_icrl.constraints.wrappers import GACLRewardWrapper, LearnedCostVecEnvWrapper
from sb3_icrl.icrl.recorder import NominalData, NominalTrajectory, TrajectoryRecorderVecEnvWrapper


class Minibatch(NamedTuple):
    """
    One minibatch of a constraint update.

    :param expert_obs: Expert observations
    :param expert_acts: Expert actions
    :param nominal_obs: Nominal observations (raw)
    :param nominal_acts: Nominal actions
    :param nominal_idx: Indices of the nominal pairs in the update's :class:`NominalData` (for per-pair weights)
    """

    expert_obs: np.ndarray
    expert_acts: np.ndarray
    nominal_obs: np.ndarray
    nominal_acts: np.ndarray
    nominal_idx: np.ndarray


def install_constraint(wrapper: LearnedCostVecEnvWrapper | GACLRewardWrapper, constraint_net: _ConstraintNet) -> None:
    """
    Make ``wrapper`` use ``constraint_net``: its cost ``1 - phi`` for a learned-cost wrapper, its feasibility as the
    discriminator ``D`` for GACL's reward wrapper.

    :param wrapper: The wrapper that feeds the constraint to the learner
    :param constraint_net: The constraint model
    """
    if isinstance(wrapper, GACLRewardWrapper):
        wrapper.set_discriminator(constraint_net.predict_feasibility)
    elif isinstance(wrapper, LearnedCostVecEnvWrapper):
        if wrapper.cost_fn is not None:  # (None: the learner computes the cost itself, from the same model)
            wrapper.set_cost_fn(constraint_net.cost)
    else:
        raise TypeError(f"Expected a LearnedCostVecEnvWrapper or GACLRewardWrapper, got {type(wrapper).__name__}.")


class ICRLTrainer(BaseCallback):
    """
    Base of the constraint-model updates of BC2L, GACL, MECL and VICRL (the ``ICRLTrainer`` family).

    At the end of a rollout, once ``update_every`` timesteps have passed since the last update, it takes up to
    ``n_nominal_trajectories`` of the trajectories the learner finished since then (raw observations and actions,
    from the :class:`TrajectoryRecorderVecEnvWrapper`), adds those remembered from earlier updates (``nominal_memory``),
    makes ``constraint_steps`` passes over them in minibatches of ``batch_size`` nominal pairs (each with as many
    random expert pairs), and logs under ``constraint/``.
    The update happens before the policy update, so the rollout just collected keeps the costs it was judged with.

    Subclasses implement :meth:`loss` and may override :meth:`_before_update`, :meth:`_should_stop` and
    :meth:`install`.

    :param constraint_net: The constraint model (updated in place)
    :param optimizer: Its optimizer
    :param expert_obs: Expert observations, one row per pair
    :param expert_acts: Expert actions, one row per pair
    :param recorder: The wrapper that records the learner's trajectories (``None``: no callback use, :meth:`update`
        is called by hand, as in :func:`~sb3_icrl.icrl.tabular.tabular_icrl`)
    :param wrapper: The wrapper that feeds the constraint to the learner (``None``: nothing to install)
    :param update_every: Policy timesteps between constraint updates (checked at the end of each rollout)
    :param constraint_steps: Passes over the nominal data per update (the reference's ``backward_iterations``)
    :param batch_size: Nominal pairs per minibatch (``None``: all, one gradient step per pass)
    :param n_nominal_trajectories: Most recent trajectories used per update (the reference uses the expert count)
    :param nominal_memory: Trajectories of earlier updates kept and added to each update's nominal data (0: none, as
        the reference's MuJoCo runs). Once full, a random one makes room for each new one, as in the reference code's
        ``IRLDataQueue``, so old behaviour thins out instead of vanishing. Without it, a model fitted only to the
        learner's latest trajectories can forget a region the learner stopped visiting, and the learner comes back
        to it (seen on BlockedHalfCheetah, ``benchmarks/RESULTS.md``). Not in the model zip: it travels with the rest
        of the trainer's state (:meth:`state_dict`), which ``train.py`` checkpoints save beside the model
    :param learning_rate_decay: Factor applied to the optimiser's learning rate after each update (1: constant). The
        reference code anneals the constraint learning rate by 0.9 per outer iteration (``anneal_clr_by_factor``), so
        that late updates, when the learner already looks like the expert, move the constraint less. The rate travels
        with the optimiser's state, so a resumed run goes on from where it was
    :param match_tolerance: Skip an update when the learner already looks as feasible as the expert under the current
        model: the expert's mean feasibility less that of the learner's new trajectories, measured before the update
        (logged as ``constraint/feasibility_gap``), is below this (``None``: never skip). Once the learner stays in
        the expert's region, a classifier trained on expert vs learner can only go on by telling their gaits apart,
        and the learner, charged for its own gait, falls back (seen on BlockedHalfCheetah, ``benchmarks/RESULTS.md``).
        A skipped update leaves the model, its learning rate and the budget as they were (``constraint/skipped`` is
        1). The gap is small too while the model has learned nothing yet, hence ``match_warmup_updates``
    :param match_two_sided: Skip only while the gap's size is below ``match_tolerance``. One-sided (the default), a
        learner that looks *more* feasible than the expert skips its updates too, however far: a learner that ran into
        a region where the model extrapolates a low cost (past the true line, where neither the expert nor the early
        learner went) keeps it, and the model is frozen while the learner breaks the constraint (seen on
        BlockedHalfCheetahReach, ``benchmarks/log/2026-11-29.md``). Two-sided, that learner gets an update. Needs
        ``match_tolerance``
    :param match_warmup_updates: Updates always made before ``match_tolerance`` may skip one (counted over the
        model's life: saved with it, so a resumed run does not warm up again)
    :param seed: Seed of the minibatch sampling (the model's seed, when it has one, replaces it before the first update)
    :param budget_from_expert: Set the learner's cost budget to the expert's mean learned cost per step after each
        update (and before the first), logged as ``constraint/cost_budget``: the learner is asked to be as feasible
        as the expert under the current model, not more. With a budget of 0 on a cost ``1 - phi`` that never reaches
        0, the multiplier grows without end and the reward fades out of the policy loss. Needs a PPO-Lagrangian
        learner with ``budget_statistic="step"``
    :param verbose: Verbosity level
    """

    #: The kind of constraint model the trainer's loss needs
    constraint_net_type: ClassVar[type[_ConstraintNet]] = _ConstraintNet

    def __init__(
        self,
        constraint_net: _ConstraintNet,
        optimizer: th.optim.Optimizer,
        expert_obs: np.ndarray,
        expert_acts: np.ndarray,
        recorder: TrajectoryRecorderVecEnvWrapper | None,
        wrapper: LearnedCostVecEnvWrapper | GACLRewardWrapper | None,
        update_every: int,
        constraint_steps: int = 5,
        batch_size: int | None = None,
        n_nominal_trajectories: int = 50,
        nominal_memory: int = 0,
        learning_rate_decay: float = 1.0,
        match_tolerance: float | None = None,
        match_two_sided: bool = False,
        match_warmup_updates: int = 3,
        seed: int | None = None,
        budget_from_expert: bool = False,
        verbose: int = 0,
    ):
        super().__init__(verbose)
        if update_every < 1 or constraint_steps < 1 or n_nominal_trajectories < 1:
            raise ValueError(
                "`update_every`, `constraint_steps` and `n_nominal_trajectories` must be >= 1, got "
                f"{update_every}, {constraint_steps} and {n_nominal_trajectories}."
            )
        if batch_size is not None and batch_size < 1:
            raise ValueError(f"`batch_size` must be >= 1 or None, got {batch_size}.")
        if nominal_memory < 0:
            raise ValueError(f"`nominal_memory` must be >= 0 (0: no memory), got {nominal_memory}.")
        if not 0.0 < learning_rate_decay <= 1.0:
            raise ValueError(f"`learning_rate_decay` must be in (0, 1] (1: constant rate), got {learning_rate_decay}.")
        if match_tolerance is not None and match_tolerance <= 0.0:
            raise ValueError(f"`match_tolerance` must be > 0 or None (never skip), got {match_tolerance}.")
        if not isinstance(match_two_sided, bool):
            raise TypeError(f"`match_two_sided` must be True or False, got {match_two_sided!r}.")
        if match_two_sided and match_tolerance is None:
            raise ValueError("`match_two_sided=True` needs a `match_tolerance` (without one no update is ever skipped).")
        if match_warmup_updates < 1:
            raise ValueError(
                f"`match_warmup_updates` must be >= 1 (the first model is not fitted yet), got {match_warmup_updates}."
            )
        if len(expert_obs) == 0 or len(expert_obs) != len(expert_acts):
            raise ValueError(
                f"Need as many expert observations as actions (> 0), got {len(expert_obs)} and {len(expert_acts)}."
            )
        if not isinstance(constraint_net, self.constraint_net_type):
            raise TypeError(
                f"{type(self).__name__} trains a {self.constraint_net_type.__name__}, got {type(constraint_net).__name__}."
            )
        self.constraint_net = constraint_net
        self.optimizer = optimizer
        self.expert_obs = expert_obs
        self.expert_acts = expert_acts
        self.recorder = recorder
        self.wrapper = wrapper
        self.update_every = int(update_every)
        self.constraint_steps = int(constraint_steps)
        self.batch_size = batch_size
        self.n_nominal_trajectories = int(n_nominal_trajectories)
        self.nominal_memory = int(nominal_memory)
        self.learning_rate_decay = float(learning_rate_decay)
        self.match_tolerance = match_tolerance
        self.match_two_sided = match_two_sided
        self.match_warmup_updates = int(match_warmup_updates)
        self.remembered: list[NominalTrajectory] = []
        self.budget_from_expert = budget_from_expert
        self.n_updates = 0
        self._last_update = 0
        self._rng = np.random.default_rng(seed)
        # Set by load_state_dict: the next _init_callback keeps the restored counters and random state
        self._restored = False

    # ------------------------------------------------------------------ callback hooks

    def _init_callback(self) -> None:
        if self.budget_from_expert and getattr(self.model, "budget_statistic", None) != "step":
            raise ValueError(
                "`budget_from_expert` sets a per-step budget: the learner must be a PPOLagrangian with "
                f"budget_statistic='step', got {type(self.model).__name__} with "
                f"budget_statistic={getattr(self.model, 'budget_statistic', None)!r}."
            )
        if self._restored:
            # A resumed run: the step of the last update and the sampling sequence go on from the checkpoint
            self._restored = False
        else:
            self._last_update = self.num_timesteps
            if self.model.seed is not None and self.n_updates == 0:
                # Seeded once: a later learn() call continues the sequence
                self._rng = np.random.default_rng(self.model.seed)
        # The update count lives on the model too, so that it is saved with it
        self.n_updates = max(self.n_updates, int(getattr(self.model, "n_constraint_updates", 0)))
        self.install()

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        if self.num_timesteps - self._last_update < self.update_every:
            return
        if self.recorder is None:
            raise RuntimeError("This trainer has no trajectory recorder: it cannot run as a callback.")
        trajectories = self.recorder.pop_trajectories(self.n_nominal_trajectories)
        if not trajectories:
            # Episodes longer than a rollout: wait until one ends
            if self.verbose >= 1:
                print("ICRL: no finished nominal trajectory yet, constraint update postponed")
            return
        self._last_update = self.num_timesteps
        n_recalled = len(self.remembered)
        gap = self.feasibility_gap(NominalData.from_trajectories(trajectories))
        if self.skips_update(gap):
            stats: dict[str, float] = {"skipped": 1.0}
        else:
            stats = {**self.update(NominalData.from_trajectories(self.remembered + trajectories)), "skipped": 0.0}
            self.model.n_constraint_updates = self.n_updates  # type: ignore[attr-defined]
            self.install()
        stats["feasibility_gap"] = gap
        self.remember(trajectories)
        if self.nominal_memory > 0:
            stats["n_remembered_trajectories"] = float(n_recalled)
        if self.budget_from_expert:
            stats["cost_budget"] = float(self.model.cost_budget[0])  # type: ignore[attr-defined]
        for key, value in stats.items():
            self.logger.record(f"constraint/{key}", value)

    # ------------------------------------------------------------------ checkpoint state

    def state_dict(self) -> dict[str, Any]:
        """
        What a resumed run needs beyond the model zip (which holds the constraint net, its optimiser and the update
        count): the remembered nominal trajectories (``nominal_memory``), the trajectories finished since the last
        update and not used yet, the step of the last update and the state of the minibatch sampler. Plain numpy
        arrays and numbers only, so that it pickles with any version of the class.

        :return: The state, for :meth:`load_state_dict`
        """
        pending = list(self.recorder.finished) if self.recorder is not None else []
        return {
            "n_updates": int(self.n_updates),
            "last_update": int(self._last_update),
            "rng": self._rng.bit_generator.state,
            "remembered": [(trajectory.obs, trajectory.acts) for trajectory in self.remembered],
            "pending": [(trajectory.obs, trajectory.acts) for trajectory in pending],
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """
        Go on from a :meth:`state_dict`: the next ``learn()`` keeps these counters instead of starting them afresh.

        :param state: From :meth:`state_dict` (of a trainer of the same model)
        """
        missing = {"n_updates", "last_update", "rng", "remembered", "pending"} - set(state)
        if missing:
            raise ValueError(f"Not an ICRL trainer state: {sorted(missing)} missing (saved by ICRLTrainer.state_dict?).")
        self.n_updates = int(state["n_updates"])
        self._last_update = int(state["last_update"])
        self._rng = np.random.default_rng()
        self._rng.bit_generator.state = state["rng"]
        self.remembered = [NominalTrajectory(np.asarray(obs), np.asarray(acts)) for obs, acts in state["remembered"]]
        if self.recorder is not None:
            self.recorder.finished.clear()
            pending = (NominalTrajectory(np.asarray(obs), np.asarray(acts)) for obs, acts in state["pending"])
            self.recorder.finished.extend(pending)
        self._restored = True

    # ------------------------------------------------------------------ nominal data

    def skips_update(self, gap: float) -> bool:
        """
        Whether ``match_tolerance`` skips the update due now (never during the warm-up).

        :param gap: The :meth:`feasibility_gap` of the learner's new trajectories
        :return: ``True`` to skip it
        """
        if self.match_tolerance is None or self.n_updates < self.match_warmup_updates:
            return False
        return (abs(gap) if self.match_two_sided else gap) < self.match_tolerance

    def feasibility_gap(self, nominal: NominalData) -> float:
        """
        The expert's mean feasibility less the learner's, under the current model.

        :param nominal: The learner's trajectories
        :return: The gap (negative when the learner looks the more feasible)
        """
        expert = float(np.mean(self._feasibility(self.expert_obs, self.expert_acts)))
        return expert - float(np.mean(self._feasibility(nominal.obs, nominal.acts)))

    def remember(self, trajectories: list[NominalTrajectory]) -> None:
        """
        Keep ``trajectories`` for later updates, up to ``nominal_memory`` in all; once full, each new one replaces a
        random kept one.

        :param trajectories: The nominal trajectories of the update just made
        """
        if self.nominal_memory == 0:
            return
        for trajectory in trajectories:
            if len(self.remembered) < self.nominal_memory:
                self.remembered.append(trajectory)
            else:
                self.remembered[int(self._rng.integers(self.nominal_memory))] = trajectory

    # ------------------------------------------------------------------ the update

    def install(self) -> None:
        """Feed the (updated) constraint model to the learner's wrapper, and the expert's cost to its budget if asked."""
        if self.wrapper is not None:
            install_constraint(self.wrapper, self.constraint_net)
        if self.budget_from_expert and getattr(self, "model", None) is not None:
            self.model.set_cost_budget(self.expert_mean_cost())  # type: ignore[attr-defined]

    def expert_mean_cost(self) -> float:
        """The expert's mean learned cost per step (``1 - phi`` as the learner's wrapper computes it)."""
        return float(np.mean(self.constraint_net.cost(self.expert_obs, self.expert_acts)))

    @abstractmethod
    def loss(self, batch: Minibatch) -> tuple[th.Tensor, dict[str, float]]:
        """
        The loss of one minibatch.

        :param batch: Expert and nominal pairs
        :return: The loss to minimise and scalars to log (averaged over the minibatches)
        """

    def _before_update(self, nominal: NominalData) -> None:
        """Called once per update before the first pass (e.g. MECL stores the old feasibility)."""

    def _should_stop(self, nominal: NominalData) -> bool:
        """Called before each pass; ``True`` ends the update early (e.g. MECL's KL bound)."""
        return False

    def _feasibility(self, obs: np.ndarray, acts: np.ndarray) -> np.ndarray:
        """Mean feasibility used for logging (the cost is ``1 - phi``)."""
        return 1.0 - self.constraint_net.cost(obs, acts)

    def update(self, nominal: NominalData) -> dict[str, float]:
        """
        Update the constraint model on the expert data vs ``nominal``.

        :param nominal: The learner's recent pairs, grouped by trajectory
        :return: What to log: ``loss``, ``expert_feasibility``, ``nominal_feasibility``, the loss parts, ``n_passes``...
        """
        self.constraint_net.train()
        self._before_update(nominal)
        n_nominal = len(nominal)
        batch_size = n_nominal if self.batch_size is None else min(self.batch_size, n_nominal)
        logs: dict[str, list[float]] = {}
        n_passes = 0
        for _ in range(self.constraint_steps):
            if self._should_stop(nominal):
                break
            n_passes += 1
            order = self._rng.permutation(n_nominal)
            for start in range(0, n_nominal, batch_size):
                nominal_idx = order[start : start + batch_size]
                expert_idx = self._rng.integers(0, len(self.expert_obs), size=len(nominal_idx))
                loss, parts = self.loss(
                    Minibatch(
                        self.expert_obs[expert_idx],
                        self.expert_acts[expert_idx],
                        nominal.obs[nominal_idx],
                        nominal.acts[nominal_idx],
                        nominal_idx,
                    )
                )
                self.optimizer.zero_grad()
                loss.backward()
                self.optimizer.step()
                for key, value in {"loss": float(loss.item()), **parts}.items():
                    logs.setdefault(key, []).append(value)
        self.constraint_net.eval()
        self.n_updates += 1
        stats = {key: float(np.mean(values)) for key, values in logs.items()}
        stats["learning_rate"] = float(self.optimizer.param_groups[0]["lr"])  # the rate this update used
        for group in self.optimizer.param_groups:
            group["lr"] *= self.learning_rate_decay
        stats.update(self._after_update_stats(nominal))
        stats["expert_feasibility"] = float(np.mean(self._feasibility(self.expert_obs, self.expert_acts)))
        stats["nominal_feasibility"] = float(np.mean(self._feasibility(nominal.obs, nominal.acts)))
        stats["n_passes"] = float(n_passes)
        stats["n_nominal_trajectories"] = float(len(nominal.episode_lengths))
        stats["n_updates"] = float(self.n_updates)
        return stats

    def _after_update_stats(self, nominal: NominalData) -> dict[str, Any]:
        """Extra statistics after the update (e.g. MECL's importance weights)."""
        return {}
