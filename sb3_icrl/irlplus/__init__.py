"""IRL-Plus (Hugessen et al., NeurIPS 2024): inverse RL on a cost as a negative reward, on SAC or PPO."""

from sb3_icrl.irlplus.irlplus import IRLPLUS_LAGRANGE_KWARGS, IRLPlus, IRLPlusPPO, IRLPlusTrainer

__all__ = ["IRLPLUS_LAGRANGE_KWARGS", "IRLPlus", "IRLPlusPPO", "IRLPlusTrainer"]
