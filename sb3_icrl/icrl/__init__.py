"""Shared machinery of the ICRL algorithms: the trainer callback, nominal-data recording, the algorithm base."""

from sb3_icrl.icrl.base import DEFAULT_LAGRANGE_KWARGS, ICRLAlgorithmMixin, LagrangianICRL
from sb3_icrl.icrl.callbacks import TrueConstraintLogger
from sb3_icrl.icrl.off_policy import OffPolicyICRL
from sb3_icrl.icrl.recorder import NominalData, NominalTrajectory, TrajectoryRecorderVecEnvWrapper
from sb3_icrl.icrl.tabular import TabularICRLResult, cost_table, tabular_icrl
from sb3_icrl.icrl.trainer import ICRLTrainer, install_constraint

__all__ = [
    "DEFAULT_LAGRANGE_KWARGS",
    "ICRLAlgorithmMixin",
    "ICRLTrainer",
    "LagrangianICRL",
    "NominalData",
    "NominalTrajectory",
    "OffPolicyICRL",
    "TabularICRLResult",
    "TrajectoryRecorderVecEnvWrapper",
    "TrueConstraintLogger",
    "cost_table",
    "install_constraint",
    "tabular_icrl",
]
