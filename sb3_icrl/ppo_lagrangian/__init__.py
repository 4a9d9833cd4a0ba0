from sb3_icrl.ppo_lagrangian.policies import CnnPolicy, MlpPolicy
from sb3_icrl.ppo_lagrangian.ppo_lagrangian import PPOLagrangian

__all__ = ["CnnPolicy", "MlpPolicy", "PPOLagrangian"]
