"""
The registry of algorithms: the names the command line, the recipes, the run folders and the benchmark suites know
each algorithm by, its class, whether it learns a constraint from demonstrations, and its hyper-parameter file.

sb3-icrl's own algorithms are registered here; a user's method joins them with :func:`register_algorithm`, called in a
module that ``--gym-packages`` (or a suite's ``gym_packages``) imports. The env ids' helpers
(:mod:`sb3_icrl.common.env_ids`) are re-exported, so that one module answers "what can I name on the command line".
"""

import os
import pathlib
import re

from stable_baselines3 import PPO
from stable_baselines3.common.base_class import BaseAlgorithm

from sb3_icrl.bc2l import BC2L
from sb3_icrl.common.env_ids import NAMESPACE, env_name, import_gym_packages, resolve_env_id
from sb3_icrl.gacl import GACL
from sb3_icrl.icrl.base import ICRLAlgorithmMixin
from sb3_icrl.irlplus import IRLPlus, IRLPlusPPO
from sb3_icrl.mecl import MECL
from sb3_icrl.ppo_lagrangian import PPOLagrangian
from sb3_icrl.vicrl import VICRL

#: Command-line name -> algorithm class
ALGOS: dict[str, type[BaseAlgorithm]] = {
    "ppo": PPO,
    "ppolag": PPOLagrangian,
    "gacl": GACL,
    "bc2l": BC2L,
    "mecl": MECL,
    "vicrl": VICRL,
    "irlplus": IRLPlus,
    "irlplusppo": IRLPlusPPO,
}
#: Algorithms that learn a constraint from demonstrations (a list: :func:`register_algorithm` appends to it in place,
#: so that every module that imported it sees a user's method)
ICRL_ALGOS: list[str] = ["gacl", "bc2l", "mecl", "vicrl", "irlplus", "irlplusppo"]
#: Algorithms that can learn on another algorithm's forward learner (``forward_recipe``): the reference rows of a
#: benchmark, unconstrained PPO and PPO-Lagrangian on the true cost (the oracle)
REFERENCE_ALGOS = ("ppo", "ppolag")
#: Where the shipped hyper-parameter files live: ``sb3_icrl/zoo_hyperparams`` (package data, so installed wheels have
#: them too); the repository root's ``zoo_hyperparams`` is a link to it, where rl-zoo users look for them
DEFAULT_HYPERPARAMS_DIR = pathlib.Path(__file__).resolve().parent / "zoo_hyperparams"
#: Hyper-parameter files of registered algorithms that do not ship theirs in :data:`DEFAULT_HYPERPARAMS_DIR`
HYPERPARAMS_FILES: dict[str, pathlib.Path] = {}
#: A name the command line, file names and suite keys can all carry
_ALGO_NAME = re.compile(r"^[a-z][a-z0-9_]*$")


class RegistrationError(ValueError):
    """An algorithm that cannot be registered under the name asked for."""


def register_algorithm(
    name: str,
    algo_class: type[BaseAlgorithm],
    icrl: bool | None = None,
    hyperparams: str | os.PathLike | None = None,
) -> None:
    """
    Make ``algo_class`` trainable as ``--algo name`` by ``train.py``, ``enjoy.py``, ``compare`` and benchmark suites.

    Call it at the top level of a module and name that module with ``--gym-packages`` (or in a suite's
    ``gym_packages``): the benchmark's training processes import it too. Registering the same class under the same
    name again does nothing, so that the module can be imported more than once.

    :param name: The command-line name (lower case letters, digits and ``_``, starting with a letter)
    :param algo_class: A subclass of SB3's ``BaseAlgorithm``
    :param icrl: Whether it learns a constraint from demonstrations (``--demonstrations``, the ICRL metrics);
        ``None``: whether it is an ICRL algorithm of this library (a subclass of
        :class:`~sb3_icrl.icrl.base.ICRLAlgorithmMixin`)
    :param hyperparams: Its hyper-parameter file (``default`` and env names mapped to entries, as
        ``zoo_hyperparams/<algo>.yml``); ``None``: ``zoo_hyperparams/<name>.yml``, or ``-conf`` on each run
    :raises RegistrationError: For a malformed or taken name, a class that is no ``BaseAlgorithm``, or a file that
        does not exist
    """
    if not isinstance(name, str) or not _ALGO_NAME.match(name):
        raise RegistrationError(
            f"Algorithm name {name!r}: use lower case letters, digits and '_', starting with a letter (e.g. 'mymethod')."
        )
    if not (isinstance(algo_class, type) and issubclass(algo_class, BaseAlgorithm)):
        raise RegistrationError(
            f"register_algorithm({name!r}, ...): {algo_class!r} is not a subclass of stable_baselines3's BaseAlgorithm."
        )
    if icrl is None:
        icrl = issubclass(algo_class, ICRLAlgorithmMixin)
    hyperparams_path = None if hyperparams is None else pathlib.Path(hyperparams).resolve()
    if hyperparams_path is not None and not hyperparams_path.is_file():
        raise RegistrationError(f"register_algorithm({name!r}, ...): no hyper-parameter file {hyperparams}.")
    if name in ALGOS:
        same = ALGOS[name] is algo_class and (name in ICRL_ALGOS) == icrl and HYPERPARAMS_FILES.get(name) == hyperparams_path
        if same:
            return
        raise RegistrationError(
            f"The algorithm name {name!r} is taken (by {ALGOS[name].__module__}.{ALGOS[name].__qualname__}): pick another."
        )
    ALGOS[name] = algo_class
    if icrl:
        ICRL_ALGOS.append(name)
    if hyperparams_path is not None:
        HYPERPARAMS_FILES[name] = hyperparams_path


def is_icrl(algo: str) -> bool:
    """
    :param algo: A registered command-line name
    :return: Whether it learns a constraint from demonstrations
    """
    return algo in ICRL_ALGOS


def hyperparams_file(algo: str, directory: str | os.PathLike | None = None) -> pathlib.Path:
    """
    :param algo: A registered command-line name
    :param directory: A folder of ``<algo>.yml`` files, which takes precedence (rl-zoo's ``--hyperparams-dir``)
    :return: The hyper-parameter file of ``algo``: the one it was registered with, else the shipped one
    """
    if directory is not None:
        return pathlib.Path(directory) / f"{algo}.yml"
    return HYPERPARAMS_FILES.get(algo, DEFAULT_HYPERPARAMS_DIR / f"{algo}.yml")


def unknown_algo_message(algo: str) -> str:
    """
    :param algo: A name that is not registered
    :return: What to say: the names there are, and how to add one
    """
    return (
        f"Unknown algo {algo!r}: use one of {', '.join(ALGOS)}, or register your own with "
        "sb3_icrl.register_algorithm in a module you name with --gym-packages MODULE."
    )


__all__ = [
    "ALGOS",
    "DEFAULT_HYPERPARAMS_DIR",
    "ICRL_ALGOS",
    "NAMESPACE",
    "REFERENCE_ALGOS",
    "RegistrationError",
    "env_name",
    "hyperparams_file",
    "import_gym_packages",
    "is_icrl",
    "register_algorithm",
    "resolve_env_id",
    "unknown_algo_message",
]
