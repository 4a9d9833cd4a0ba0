"""BC2L: a binary classifier of expert (feasible) vs nominal pairs, its cost ``1 - phi`` fed to PPO-Lagrangian."""

from typing import ClassVar

import torch as th

from sb3_icrl.constraints.losses import ConstraintLoss, bc2l_loss
from sb3_icrl.constraints.networks import FeasibilityNet, _ConstraintNet
from sb3_icrl.icrl.base import LagrangianICRL
from sb3_icrl.icrl.trainer import ICRLTrainer, Minibatch


class BC2LTrainer(ICRLTrainer):
    """
    BC2L's constraint update: binary cross-entropy, expert pairs labelled feasible (1), nominal pairs 0
    (:func:`~sb3_icrl.constraints.bc2l_loss`); no importance weights, no regulariser. Arguments: see
    :class:`~sb3_icrl.icrl.ICRLTrainer`; the constraint model must be a :class:`~sb3_icrl.constraints.FeasibilityNet`.
    """

    constraint_net_type: ClassVar[type[_ConstraintNet]] = FeasibilityNet

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


class BC2L(LagrangianICRL):
    """
    Binary Classifier Constraint Learning (the paper's section 3.2): a feasibility classifier ``phi(s, a)`` trained
    with :class:`BC2LTrainer` on expert vs the learner's own pairs, and a PPO-Lagrangian policy on the cost
    ``1 - phi``. Arguments: see :class:`~sb3_icrl.icrl.LagrangianICRL`.
    """

    constraint_net_class: ClassVar[type[_ConstraintNet]] = FeasibilityNet
    default_trainer_class: ClassVar[type[ICRLTrainer]] = BC2LTrainer
