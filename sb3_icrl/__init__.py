"""sb3-icrl: Inverse Constrained Reinforcement Learning on Stable-Baselines3."""

import os

from sb3_icrl.ppo_lagrangian import PPOLagrangian

# Read version from file
version_file = os.path.join(os.path.dirname(__file__), "version.txt")
with open(version_file) as file_handler:
    __version__ = file_handler.read().strip()

__all__ = ["PPOLagrangian", "__version__"]
