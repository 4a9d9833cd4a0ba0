"""rl-baselines3-zoo style training entry point: ``python train.py --algo mecl --env BlockedHalfCheetah-v0``."""

from sb3_icrl.hyperparams import load_hyperparams
from sb3_icrl.registry import ALGOS, ICRL_ALGOS, resolve_env_id
from sb3_icrl.zoo.train import get_parser, main, train


def register_rl_zoo3() -> dict:
    """Add sb3-icrl's algorithms to rl_zoo3's ``ALGOS`` (:func:`sb3_icrl.zoo.rl_zoo3.register_rl_zoo3`)."""
    # Imported here: ``python -m sb3_icrl.zoo.rl_zoo3`` must not find the module imported already
    from sb3_icrl.zoo.rl_zoo3 import register_rl_zoo3 as register

    return register()


__all__ = ["ALGOS", "ICRL_ALGOS", "get_parser", "load_hyperparams", "main", "register_rl_zoo3", "resolve_env_id", "train"]
