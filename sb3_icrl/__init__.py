"""sb3-icrl: Inverse Constrained Reinforcement Learning on Stable-Baselines3."""

import os

import sb3_icrl.common.envs  # (registers the tiny test env with gymnasium)
import sb3_icrl.envs  # noqa: F401  (registers the benchmark envs with gymnasium)
from sb3_icrl.bc2l import BC2L
from sb3_icrl.common.constraint_spec import ConstraintSpec, FeatureConstraint, declare_constraint, get_constraint_spec
from sb3_icrl.common.evaluation import ConstraintEvaluation, evaluate_constraint
from sb3_icrl.gacl import GACL
from sb3_icrl.irlplus import IRLPlus, IRLPlusPPO
from sb3_icrl.mecl import MECL
from sb3_icrl.pi_lagrangian import PILagrangian
from sb3_icrl.ppo_lagrangian import PPOLagrangian
from sb3_icrl.registry import register_algorithm
from sb3_icrl.sac_lagrangian import SACLagrangian
from sb3_icrl.vicrl import VICRL

# Read version from file
version_file = os.path.join(os.path.dirname(__file__), "version.txt")
with open(version_file) as file_handler:
    __version__ = file_handler.read().strip()

__all__ = [
    "BC2L",
    "GACL",
    "MECL",
    "VICRL",
    "ConstraintEvaluation",
    "ConstraintSpec",
    "FeatureConstraint",
    "IRLPlus",
    "IRLPlusPPO",
    "PILagrangian",
    "PPOLagrangian",
    "SACLagrangian",
    "__version__",
    "declare_constraint",
    "evaluate_constraint",
    "get_constraint_spec",
    "register_algorithm",
]
