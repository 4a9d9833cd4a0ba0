"""BC2L: a binary classifier of expert (feasible) vs nominal pairs, its cost ``1 - phi`` fed to PPO-Lagrangian."""

from typing import Any, ClassVar

import numpy as np
import torch as th

from sb3_icrl.constraints.losses import ConstraintLoss, bc2l_loss, bc2l_trajectory_loss
from sb3_icrl.constraints.networks import FeasibilityNet, _ConstraintNet
from sb3_icrl.icrl.base import LagrangianICRL
from sb3_icrl.icrl.recorder import NominalData
from sb3_icrl.icrl.trainer import ICRLTrainer, Minibatch


class BC2LTrainer(ICRLTrainer):
    """
    BC2L's constraint update: binary cross-entropy, expert pairs labelled feasible (1), nominal pairs 0
    (:func:`~sb3_icrl.constraints.bc2l_loss`); no importance weights, no regulariser. Other arguments: see
    :class:`~sb3_icrl.icrl.ICRLTrainer`; the constraint model must be a :class:`~sb3_icrl.constraints.FeasibilityNet`.

    :param expert_episode_lengths: Length of each expert trajectory, in the order of ``expert_obs``. When given, the
        classifier labels whole trajectories instead of pairs, a trajectory being feasible when all its pairs are
        (:func:`~sb3_icrl.constraints.bc2l_trajectory_loss`, the reference code's grid-world update): each
        minibatch then holds ``batch_size`` nominal trajectories (``None``: all) and as many random expert ones.
    """

    constraint_net_type: ClassVar[type[_ConstraintNet]] = FeasibilityNet

    def __init__(self, *args: Any, expert_episode_lengths: np.ndarray | list[int] | None = None, **kwargs: Any):
        super().__init__(*args, **kwargs)
        self.expert_episode_lengths: np.ndarray | None = None
        if expert_episode_lengths is not None:
            lengths = np.asarray(expert_episode_lengths, dtype=np.int64)
            if lengths.ndim != 1 or lengths.size == 0 or np.any(lengths < 1) or int(lengths.sum()) != len(self.expert_obs):
                raise ValueError(
                    f"`expert_episode_lengths` must be positive and sum to the {len(self.expert_obs)} expert pairs, "
                    f"got {expert_episode_lengths!r}."
                )
            self.expert_episode_lengths = lengths
            self._expert_starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])

    def binary_loss(self, expert_feasibility: th.Tensor, nominal_feasibility: th.Tensor) -> ConstraintLoss:
        """The expert-vs-nominal cross-entropy (GACL's trainer swaps in its own)."""
        return bc2l_loss(expert_feasibility, nominal_feasibility)

    def loss(self, batch: Minibatch) -> tuple[th.Tensor, dict[str, float]]:
        assert isinstance(self.constraint_net, FeasibilityNet)
        result = self.binary_loss(
            self.constraint_net.feasibility(batch.expert_obs, batch.expert_acts),
            self.constraint_net.feasibility(batch.nominal_obs, batch.nominal_acts),
        )
        return result.total, {"loss_expert": float(result.expert.item()), "loss_nominal": float(result.nominal.item())}

    def _trajectory_pairs(self, starts: np.ndarray, lengths: np.ndarray) -> np.ndarray:
        """Indices of the pairs of the trajectories that start at ``starts``, trajectory after trajectory."""
        return np.concatenate([np.arange(start, start + length) for start, length in zip(starts, lengths, strict=True)])

    def update(self, nominal: NominalData) -> dict[str, float]:
        """
        Update the classifier on the expert data vs ``nominal``: per pair (:meth:`ICRLTrainer.update`), or per
        trajectory when the expert episode lengths were given.

        :param nominal: The learner's recent pairs, grouped by trajectory
        :return: What to log (as :meth:`ICRLTrainer.update`)
        """
        if self.expert_episode_lengths is None:
            return super().update(nominal)
        assert isinstance(self.constraint_net, FeasibilityNet)
        self.constraint_net.train()
        nominal_lengths = np.asarray(nominal.episode_lengths, dtype=np.int64)
        nominal_starts = np.concatenate([[0], np.cumsum(nominal_lengths)[:-1]])
        n_trajectories = len(nominal_lengths)
        batch_size = n_trajectories if self.batch_size is None else min(self.batch_size, n_trajectories)
        logs: dict[str, list[float]] = {}
        for _ in range(self.constraint_steps):
            order = self._rng.permutation(n_trajectories)
            for start in range(0, n_trajectories, batch_size):
                nominal_idx = order[start : start + batch_size]
                expert_idx = self._rng.integers(0, len(self.expert_episode_lengths), size=len(nominal_idx))
                expert_pairs = self._trajectory_pairs(self._expert_starts[expert_idx], self.expert_episode_lengths[expert_idx])
                nominal_pairs = self._trajectory_pairs(nominal_starts[nominal_idx], nominal_lengths[nominal_idx])
                result = bc2l_trajectory_loss(
                    self.constraint_net.feasibility(self.expert_obs[expert_pairs], self.expert_acts[expert_pairs]),
                    self.expert_episode_lengths[expert_idx],
                    self.constraint_net.feasibility(nominal.obs[nominal_pairs], nominal.acts[nominal_pairs]),
                    nominal_lengths[nominal_idx],
                )
                self.optimizer.zero_grad()
                result.total.backward()
                self.optimizer.step()
                for key, value in (("loss", result.total), ("loss_expert", result.expert), ("loss_nominal", result.nominal)):
                    logs.setdefault(key, []).append(float(value.item()))
        self.constraint_net.eval()
        self.n_updates += 1
        stats = {key: float(np.mean(values)) for key, values in logs.items()}
        stats["expert_feasibility"] = float(np.mean(self._feasibility(self.expert_obs, self.expert_acts)))
        stats["nominal_feasibility"] = float(np.mean(self._feasibility(nominal.obs, nominal.acts)))
        stats["n_passes"] = float(self.constraint_steps)
        stats["n_nominal_trajectories"] = float(n_trajectories)
        stats["n_updates"] = float(self.n_updates)
        return stats


class BC2L(LagrangianICRL):
    """
    Binary Classifier Constraint Learning (the paper's section 3.2): a feasibility classifier ``phi(s, a)`` trained
    with :class:`BC2LTrainer` on expert vs the learner's own pairs, and a PPO-Lagrangian policy on the cost
    ``1 - phi``. Arguments: see :class:`~sb3_icrl.icrl.LagrangianICRL`.
    """

    constraint_net_class: ClassVar[type[_ConstraintNet]] = FeasibilityNet
    default_trainer_class: ClassVar[type[ICRLTrainer]] = BC2LTrainer
