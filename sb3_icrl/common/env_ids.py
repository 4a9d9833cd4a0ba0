"""
Env ids as the command line, the recipes and the run folders use them: gymnasium ids with sb3-icrl's ``sb3_icrl/``
namespace optional, the modules that register a user's envs, and the one name an env has in file and folder names.

Only gymnasium is imported here, so that the envs themselves can resolve ids.
"""

import importlib
from collections.abc import Sequence

import gymnasium as gym

#: The gymnasium namespace of sb3-icrl's envs
NAMESPACE = "sb3_icrl"


def import_gym_packages(packages: Sequence[str] | None) -> None:
    """
    Import the modules that register a user's envs or algorithms (rl-zoo's ``--gym-packages``).

    :param packages: Module names (``mypackage.envs``)
    :raises ValueError: When a module cannot be imported (the message says which and why)
    """
    for package in packages or []:
        try:
            importlib.import_module(package)
        except ImportError as error:
            raise ValueError(
                f"--gym-packages: cannot import {package!r} ({error}); is it installed or on PYTHONPATH?"
            ) from error


def resolve_env_id(env_id: str) -> str:
    """
    The registered gymnasium id of ``env_id``: ``BlockedHalfCheetah-v0`` becomes ``sb3_icrl/BlockedHalfCheetah-v0``;
    gymnasium's ``module:EnvId`` form imports ``module`` first (where the env registers itself).

    :param env_id: An id as typed on the command line
    :return: The registered id
    :raises ValueError: When neither ``env_id`` nor ``sb3_icrl/<env_id>`` is registered (the message lists ours)
    """
    if ":" in env_id:
        module, _, env_id = env_id.partition(":")
        import_gym_packages([module])
    if env_id in gym.registry:
        return env_id
    if f"{NAMESPACE}/{env_id}" in gym.registry:
        return f"{NAMESPACE}/{env_id}"
    ours = sorted(key.split("/", 1)[1] for key in gym.registry if key.startswith(f"{NAMESPACE}/"))
    raise ValueError(
        f"Unknown env {env_id!r}. sb3-icrl envs: {', '.join(ours)}, or any registered gymnasium id: import the module "
        "that registers yours with --gym-packages MODULE, or write the env as MODULE:EnvId."
    )


def env_name(env_id: str) -> str:
    """
    The one name of an env in run folders, ``VecNormalize`` folders, yml keys and dataset names: the id without the
    ``sb3_icrl/`` namespace or a ``MODULE:`` prefix, other namespaces joined by ``-``
    (``mymodule:myns/MyEnv-v0`` -> ``myns-MyEnv-v0``).

    :param env_id: A registered id, as typed or as resolved
    :return: The name
    """
    env_id = env_id.rpartition(":")[2]  # gymnasium's MODULE:EnvId: the module is not part of the name
    return env_id.split("/", 1)[1] if env_id.startswith(f"{NAMESPACE}/") else env_id.replace("/", "-")
