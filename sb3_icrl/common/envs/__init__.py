import gymnasium

from sb3_icrl.common.envs.corridor import ConstrainedCorridorEnv
from sb3_icrl.common.envs.velocity_cost import SAFETY_GYMNASIUM_VELOCITY_THRESHOLDS, VelocityCostWrapper

if "sb3_icrl/ConstrainedCorridor-v0" not in gymnasium.registry:
    gymnasium.register(
        id="sb3_icrl/ConstrainedCorridor-v0", entry_point="sb3_icrl.common.envs.corridor:ConstrainedCorridorEnv"
    )

__all__ = ["SAFETY_GYMNASIUM_VELOCITY_THRESHOLDS", "ConstrainedCorridorEnv", "VelocityCostWrapper"]
