from sb3_icrl.common.envs.corridor import ConstrainedCorridorEnv
from sb3_icrl.common.envs.velocity_cost import SAFETY_GYMNASIUM_VELOCITY_THRESHOLDS, VelocityCostWrapper

__all__ = ["SAFETY_GYMNASIUM_VELOCITY_THRESHOLDS", "ConstrainedCorridorEnv", "VelocityCostWrapper"]
