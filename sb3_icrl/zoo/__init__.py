"""rl-baselines3-zoo style training entry point: ``python train.py --algo mecl --env BlockedHalfCheetah-v0``."""

from sb3_icrl.zoo.hyperparams import ALGOS, ICRL_ALGOS, load_hyperparams, resolve_env_id
from sb3_icrl.zoo.train import get_parser, main, train

__all__ = ["ALGOS", "ICRL_ALGOS", "get_parser", "load_hyperparams", "main", "resolve_env_id", "train"]
