"""SAC-Lagrangian: SAC with a cost critic and a Lagrange multiplier (the off-policy forward solver)."""

from sb3_icrl.sac_lagrangian.buffers import CostReplayBuffer, CostReplayBufferSamples
from sb3_icrl.sac_lagrangian.policies import CostSACPolicy, MlpPolicy
from sb3_icrl.sac_lagrangian.sac_lagrangian import SACLagrangian

__all__ = ["CostReplayBuffer", "CostReplayBufferSamples", "CostSACPolicy", "MlpPolicy", "SACLagrangian"]
