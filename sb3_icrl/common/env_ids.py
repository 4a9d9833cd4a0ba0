"""
Env ids as the command line, the recipes and the run folders use them: gymnasium ids with sb3-icrl's ``sb3_icrl/``
namespace optional, the modules that register a user's envs, and the one name an env has in file and folder names.

Only gymnasium is imported here, so that the envs themselves can resolve ids.
"""

import difflib
import importlib
import traceback
from collections.abc import Sequence

import gymnasium as gym

#: The gymnasium namespace of sb3-icrl's envs
NAMESPACE = "sb3_icrl"


def module_error(module: str, error: Exception) -> str:
    """
    What went wrong inside a user's module as it was imported, in one line: the error and where it was raised (a
    traceback would show the import machinery's frames first).

    :param module: The module's name
    :param error: What its import raised (not an ``ImportError``)
    :return: ``importing 'module' raised ... at FILE, line N: fix the module``
    """
    if isinstance(error, SyntaxError):
        what, where = error.msg, f"{error.filename}, line {error.lineno}"
    else:
        frames = traceback.extract_tb(error.__traceback__)
        what, where = str(error), f"{frames[-1].filename}, line {frames[-1].lineno}" if frames else "an unknown place"
    return f"importing {module!r} raised {type(error).__name__}: {what} (at {where}): fix the module"


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
        except Exception as error:  # the module's own code failed
            raise ValueError(f"--gym-packages: {module_error(package, error)}.") from error


def resolve_env_id(env_id: str) -> str:
    """
    The registered gymnasium id of ``env_id``: ``BlockedHalfCheetah-v0`` becomes ``sb3_icrl/BlockedHalfCheetah-v0``;
    gymnasium's ``module:EnvId`` form imports ``module`` first (where the env registers itself).

    :param env_id: An id as typed on the command line
    :return: The registered id
    :raises ValueError: When neither ``env_id`` nor ``sb3_icrl/<env_id>`` is registered (the message lists ours)
    """
    if ":" in env_id:
        return _resolve_module_env_id(env_id)
    if env_id in gym.registry:
        return env_id
    if f"{NAMESPACE}/{env_id}" in gym.registry:
        return f"{NAMESPACE}/{env_id}"
    ours = sorted(key.split("/", 1)[1] for key in gym.registry if key.startswith(f"{NAMESPACE}/"))
    raise ValueError(
        f"Unknown env {env_id!r}. sb3-icrl envs: {', '.join(ours)}, or any registered gymnasium id: import the module "
        "that registers yours with --gym-packages MODULE, or write the env as MODULE:EnvId."
    )


def registered_constraints(env: str) -> tuple[str, ...]:
    """
    The names of the constraints an env is registered with (its ``constraints`` keyword, in the order it gives them),
    e.g. ``("velocity", "distance")``; empty for an env registered without one or not registered here.

    :param env: A registered id, or an sb3-icrl env's name without its namespace
    """
    try:
        env_id = resolve_env_id(env)
    except ValueError:
        return ()
    constraints = gym.registry[env_id].kwargs.get("constraints")
    return tuple(constraints) if isinstance(constraints, (list, tuple)) else ()


def _resolve_module_env_id(text: str) -> str:
    """:func:`resolve_env_id` of gymnasium's ``MODULE:EnvId``: errors that name the module and the id as written."""
    module, _, env_id = text.partition(":")
    if not module.strip() or not env_id.strip():
        raise ValueError(f"Env {text!r}: write MODULE:EnvId, both parts given (e.g. mypackage.envs:myns/MyEnv-v0).")
    before = set(gym.registry)
    try:
        importlib.import_module(module)
    except ImportError as error:
        raise ValueError(
            f"Env {text!r}: cannot import its module {module!r} ({error}); is it installed or on PYTHONPATH?"
        ) from error
    except Exception as error:  # the module's own code failed
        raise ValueError(f"Env {text!r}: {module_error(module, error)}.") from error
    for candidate in (env_id, f"{NAMESPACE}/{env_id}"):
        if candidate in gym.registry:
            return candidate
    # What the module registered on this import (nothing when it was imported before), else every id, for the hint
    added = sorted(set(gym.registry) - before)
    close = difflib.get_close_matches(env_id, added or list(gym.registry), n=1)
    hint = f" Did you mean {module}:{close[0]}?" if close else ""
    listed = f" It registered: {', '.join(added)}." if added else ""
    raise ValueError(
        f"Env {text!r}: {module} is imported, but no env {env_id!r} is registered: check the id, and that {module} "
        f"registers it.{listed}{hint}"
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
