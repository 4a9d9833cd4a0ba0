"""
The command line's names for the recipe reader (:mod:`sb3_icrl.hyperparams`) and the registry of algorithms and env ids
(:mod:`sb3_icrl.registry`), which live below the command line; kept so that code written against them runs on.
"""

from sb3_icrl.hyperparams import (
    EVAL_KEYS,
    UNKNOWN_ENV_ICRL_DEFAULTS,
    ZOO_KEYS,
    HyperparameterError,
    algo_kwargs,
    constructor_defaults,
    forward_learner_entry,
    import_object,
    is_mapping_argument,
    linear_schedule,
    load_hyperparams,
    preprocess_hyperparams,
    read_hyperparams_file,
    read_mapping,
)
from sb3_icrl.registry import (
    ALGOS,
    DEFAULT_HYPERPARAMS_DIR,
    ICRL_ALGOS,
    NAMESPACE,
    REFERENCE_ALGOS,
    env_name,
    import_gym_packages,
    resolve_env_id,
)

__all__ = [
    "ALGOS",
    "DEFAULT_HYPERPARAMS_DIR",
    "EVAL_KEYS",
    "ICRL_ALGOS",
    "NAMESPACE",
    "REFERENCE_ALGOS",
    "UNKNOWN_ENV_ICRL_DEFAULTS",
    "ZOO_KEYS",
    "HyperparameterError",
    "algo_kwargs",
    "constructor_defaults",
    "env_name",
    "forward_learner_entry",
    "import_gym_packages",
    "import_object",
    "is_mapping_argument",
    "linear_schedule",
    "load_hyperparams",
    "preprocess_hyperparams",
    "read_hyperparams_file",
    "read_mapping",
    "resolve_env_id",
]
