"""Constraint models, their losses and the VecEnv wrappers that feed a learned constraint to the learner."""

from sb3_icrl.constraints.losses import (
    ConstraintLoss,
    ImportanceWeights,
    bc2l_loss,
    bc2l_trajectory_loss,
    beta_kl_divergence,
    gacl_discriminator_loss,
    irl_plus_loss,
    mecl_importance_weights,
    mecl_loss,
    mecl_should_stop,
    vicrl_loss,
)
from sb3_icrl.constraints.networks import BetaFeasibilityNet, CostNet, FeasibilityNet, InputNormalizer, beta_tail_feasibility
from sb3_icrl.constraints.wrappers import GACLRewardWrapper, LearnedCostVecEnvWrapper

__all__ = [
    "BetaFeasibilityNet",
    "ConstraintLoss",
    "CostNet",
    "FeasibilityNet",
    "GACLRewardWrapper",
    "ImportanceWeights",
    "InputNormalizer",
    "LearnedCostVecEnvWrapper",
    "bc2l_loss",
    "bc2l_trajectory_loss",
    "beta_kl_divergence",
    "beta_tail_feasibility",
    "gacl_discriminator_loss",
    "irl_plus_loss",
    "mecl_importance_weights",
    "mecl_loss",
    "mecl_should_stop",
    "vicrl_loss",
]
