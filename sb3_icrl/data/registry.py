"""
Demonstrations shipped with the package, loadable by env name::

    from sb3_icrl.data import load_demonstrations

    demos = load_demonstrations("GridWorldWall-v0")  # clean expert data
    imperfect = load_demonstrations("GridWorldWall-v0", violating_fraction=0.2)

Files live in ``sb3_icrl/data/demonstrations/`` as ``<EnvName>.npz`` (clean) and
``<EnvName>_violating-<fraction>.npz``, each with its JSON sidecar. ``python -m sb3_icrl.data shipped``
regenerates them; ``python -m sb3_icrl.data list`` lists them.
"""

import os
import pathlib
import re
from collections.abc import Sequence
from dataclasses import dataclass

import gymnasium as gym
from stable_baselines3.common.vec_env import VecEnv

from sb3_icrl.data.formats import is_imitation_dataset, load_imitation_dataset
from sb3_icrl.data.generate import build_dataset, portable_path
from sb3_icrl.data.serialize import DemonstrationError, load
from sb3_icrl.data.types import Demonstrations
from sb3_icrl.envs import NAMESPACE

#: Folder of the shipped datasets
DEMONSTRATIONS_DIR = pathlib.Path(__file__).parent / "demonstrations"
_VIOLATING_SUFFIX = "_violating-"
_FILE_PATTERN = re.compile(rf"^(?P<name>.+?)(?:{_VIOLATING_SUFFIX}(?P<fraction>[0-9.]+))?\.npz$")

#: Folder of the shipped experts: ``<EnvName>.zip`` and, when trained with ``VecNormalize``, ``<EnvName>.vecnormalize.pkl``
EXPERTS_DIR = pathlib.Path(__file__).parent / "experts"


@dataclass(frozen=True)
class ShippedDataset:
    """
    How a shipped dataset is made.

    :param n_trajectories: Trajectories kept
    :param fractions: Violating fractions shipped (0: clean expert data; the others are the paper's imperfect experts)
    :param expert: ``"pilag"`` (trained on the fly, grid world) or ``"zip"`` (the PPO-Lagrangian in :data:`EXPERTS_DIR`)
    :param random_action_prob: Per-step random actions in the violating rollouts of the imperfect variants
    :param max_attempts: Episodes to try before giving up (``None``: the generator's default)
    """

    n_trajectories: int
    fractions: tuple[float, ...] = (0.0,)
    expert: str = "zip"
    random_action_prob: float = 0.5
    max_attempts: int | None = None


#: The paper's imperfect-expert fractions
IMPERFECT_FRACTIONS = (0.0, 0.2, 0.5, 0.8)
#: The shipped datasets by env name. Grid worlds: PI-Lagrangian experts (seconds). MuJoCo and driving: PPO-Lagrangian
#: experts trained with ``zoo_hyperparams/ppolag.yml`` and shipped in :data:`EXPERTS_DIR`; 20 trajectories for MuJoCo
#: (the reference uses 10-50), 100 for driving (as the paper).
SHIPPED_DATASETS: dict[str, ShippedDataset] = {
    "GridWorldWall-v0": ShippedDataset(50, IMPERFECT_FRACTIONS, "pilag"),
    "GridWorldSquare-v0": ShippedDataset(50, IMPERFECT_FRACTIONS, "pilag"),
    "GridWorldBigSquare-v0": ShippedDataset(50, IMPERFECT_FRACTIONS, "pilag"),
    "GridWorldZigzag-v0": ShippedDataset(50, IMPERFECT_FRACTIONS, "pilag"),
    "BlockedHalfCheetah-v0": ShippedDataset(20, IMPERFECT_FRACTIONS, random_action_prob=0.8),
    "BlockedAnt-v0": ShippedDataset(20, IMPERFECT_FRACTIONS),
    "BiasedPendulum-v0": ShippedDataset(20, IMPERFECT_FRACTIONS),
    # Its expert falls under heavy perturbations before it crosses; at 0.1, about one perturbed episode in 40 crosses
    "BlockedWalker-v0": ShippedDataset(20, IMPERFECT_FRACTIONS, random_action_prob=0.1, max_attempts=2000),
    "BlockedSwimmer-v0": ShippedDataset(20, IMPERFECT_FRACTIONS),
    # The binding variants (sb3_icrl.envs.binding_envs)
    "BiasedPendulumReach-v0": ShippedDataset(20, IMPERFECT_FRACTIONS),
    "BlockedHalfCheetahReach-v0": ShippedDataset(20, IMPERFECT_FRACTIONS, random_action_prob=0.2),
    # Its expert walks 0.24 m from the line: light perturbations take it across; heavy ones make it fall first
    "BlockedWalkerReach-v0": ShippedDataset(20, IMPERFECT_FRACTIONS, random_action_prob=0.1),
    "HighwayVelocity-v0": ShippedDataset(100),
    "HighwayDistance-v0": ShippedDataset(100),
    "HighwayVelocityDistance-v0": ShippedDataset(100),
}
#: Seed of the shipped datasets
SHIPPED_SEED = 0


def expert_paths(name: str, directory: str | os.PathLike = EXPERTS_DIR) -> tuple[pathlib.Path, pathlib.Path | None]:
    """
    :param name: Env name or id of a shipped expert
    :param directory: Where the experts are
    :return: The model zip and its ``VecNormalize`` statistics (``None`` when it was trained without)
    """
    base = env_name(name)
    model = pathlib.Path(directory) / f"{base}.zip"
    if not model.is_file():
        shipped = sorted(path.stem for path in pathlib.Path(directory).glob("*.zip"))
        raise FileNotFoundError(f"No shipped expert for {base!r} in {directory}. Shipped: {', '.join(shipped) or 'none'}.")
    statistics = pathlib.Path(directory) / f"{base}.vecnormalize.pkl"
    return model, statistics if statistics.is_file() else None


def env_name(env_id: str) -> str:
    """
    :param env_id: ``"sb3_icrl/GridWorldWall-v0"`` or ``"GridWorldWall-v0"``
    :return: The name without the package namespace
    """
    prefix = f"{NAMESPACE}/"
    return env_id[len(prefix) :] if env_id.startswith(prefix) else env_id


def dataset_file_name(name: str, violating_fraction: float | None = None) -> str:
    """
    :param name: Env name or id (namespace optional)
    :param violating_fraction: Share of violating trajectories; ``None`` or 0 for clean expert data
    :return: The file name of the dataset, e.g. ``"GridWorldWall-v0_violating-0.2.npz"``
    """
    base = env_name(name).replace("/", "-")
    if not violating_fraction:
        return f"{base}.npz"
    return f"{base}{_VIOLATING_SUFFIX}{float(violating_fraction):g}.npz"


def available_demonstrations(directory: str | os.PathLike = DEMONSTRATIONS_DIR) -> dict[str, list[float]]:
    """
    :param directory: Folder to look in (default: the shipped datasets)
    :return: ``env name -> sorted violating fractions`` available (0.0 is the clean expert data)
    """
    available: dict[str, list[float]] = {}
    for path in sorted(pathlib.Path(directory).glob("*.npz")):
        match = _FILE_PATTERN.match(path.name)
        if match is None:
            continue
        fraction = float(match["fraction"]) if match["fraction"] else 0.0
        available.setdefault(match["name"], []).append(fraction)
    return {name: sorted(fractions) for name, fractions in available.items()}


def _describe(available: dict[str, list[float]]) -> str:
    if not available:
        return "none"
    return "; ".join(
        f"{name} (violating_fraction {', '.join(f'{f:g}' for f in fractions)})" for name, fractions in available.items()
    )


def load_demonstrations(
    name_or_path: str | os.PathLike,
    env: gym.Env | VecEnv | str | None = None,
    violating_fraction: float | None = None,
    directory: str | os.PathLike = DEMONSTRATIONS_DIR,
    allow_env_mismatch: bool = False,
) -> Demonstrations:
    """
    Load a shipped dataset by env name, or any file written by :func:`~sb3_icrl.data.serialize.save` by path.

    :param name_or_path: Env name or id (``"GridWorldWall-v0"``, ``"sb3_icrl/GridWorldWall-v0"``), a path to an ``.npz``,
        or an ``imitation`` >= 1.0 dataset folder (:func:`~sb3_icrl.data.formats.load_imitation_dataset`)
    :param env: Optional target env whose observation and action spaces the data must fit
    :param violating_fraction: For names: the imperfect-expert variant (e.g. 0.2); ``None`` or 0: clean expert data
    :param directory: Where to look for names (default: the shipped datasets)
    :param allow_env_mismatch: With ``env``: accept data recorded on another env id whose spaces fit
    :return: The trajectories and their metadata
    """
    text = os.fspath(name_or_path)
    if os.path.isdir(text):
        if not is_imitation_dataset(text):
            raise DemonstrationError(
                f"{text} is a folder but not a dataset: give an `.npz` file, an imitation >= 1.0 dataset folder (written by "
                "`imitation.data.serialize.save`), or a shipped dataset's name."
            )
        if violating_fraction:
            raise DemonstrationError("`violating_fraction` picks a shipped variant by name; drop it for a dataset folder.")
        return load_imitation_dataset(text, env=env, allow_env_mismatch=allow_env_mismatch)
    if text.endswith(".npz") or os.path.isfile(text):
        if violating_fraction:
            raise DemonstrationError(
                "`violating_fraction` picks a shipped variant by name; a path already names one file: drop the argument."
            )
        return load(text, env=env, allow_env_mismatch=allow_env_mismatch)
    path = pathlib.Path(directory) / dataset_file_name(text, violating_fraction)
    if not path.is_file():
        raise DemonstrationError(
            f"No demonstrations named {env_name(text)!r} with violating_fraction={violating_fraction or 0:g} "
            f"in {directory}. Available: {_describe(available_demonstrations(directory))}. Generate others with "
            "`python -m sb3_icrl.data generate --env NAME --expert PATH --n 50 --out FILE` and load them by path."
        )
    return load(path, env=env, allow_env_mismatch=allow_env_mismatch)


def regenerate_shipped(
    directory: str | os.PathLike = DEMONSTRATIONS_DIR,
    names: Sequence[str] | None = None,
    experts_directory: str | os.PathLike = EXPERTS_DIR,
    verbose: bool = True,
) -> list[dict]:
    """
    Regenerate shipped datasets (:data:`SHIPPED_DATASETS`, each in its fractions): deterministic expert,
    violating trajectories dropped from the clean data, seed :data:`SHIPPED_SEED`.

    :param directory: Where to write them
    :param names: Env names to regenerate (default: all)
    :param experts_directory: Where the PPO-Lagrangian experts are
    :param verbose: Print a line per dataset
    :return: The sidecars written
    """
    unknown = sorted(set(names or ()) - set(SHIPPED_DATASETS))
    if unknown:
        raise ValueError(f"Not shipped: {unknown}. Shipped datasets: {', '.join(SHIPPED_DATASETS)}.")
    sidecars = []
    for name, spec in SHIPPED_DATASETS.items():
        if names and name not in names:
            continue
        expert, statistics = ("pilag", None) if spec.expert == "pilag" else expert_paths(name, experts_directory)
        for fraction in spec.fractions:
            path = pathlib.Path(directory) / dataset_file_name(name, fraction)
            expert_flags = "--expert pilag" if spec.expert == "pilag" else f"--expert {portable_path(expert)}"
            if statistics is not None:
                expert_flags += f" --vecnormalize {portable_path(statistics)}"
            command = (
                f"python -m sb3_icrl.data generate --env {name} {expert_flags} --n {spec.n_trajectories} --out {path.name} "
                f"--violating-fraction {fraction:g} --seed {SHIPPED_SEED} --deterministic"
            )
            if fraction:
                command += f" --random-action-prob {spec.random_action_prob:g}"
                command += f" --max-attempts {spec.max_attempts}" if spec.max_attempts is not None else ""
            sidecar = build_dataset(
                path,
                name,
                os.fspath(expert),
                spec.n_trajectories,
                vec_normalize_path=None if statistics is None else os.fspath(statistics),
                command=command,
                violating_fraction=fraction,
                random_action_prob=spec.random_action_prob,
                max_attempts=spec.max_attempts,
                seed=SHIPPED_SEED,
                deterministic=True,
            )
            sidecars.append(sidecar)
            if verbose:
                print(
                    f"{path.name}: {sidecar['n_trajectories']} trajectories, mean return {sidecar['mean_return']:.3f}, "
                    f"expert violation rate {sidecar['generation']['expert_violation_rate']:.1%}"
                )
    return sidecars


def datasets_table(directory: str | os.PathLike = DEMONSTRATIONS_DIR) -> str:
    """
    A Markdown table of the datasets in ``directory``, read from their sidecars (what the README shows).

    :param directory: Folder of the datasets
    :return: One row per file: trajectories, mean +- std return, the expert's violation rate over the episodes it
        ran (the deterministic expert, before violating ones were dropped), violating trajectories kept, file size
    """
    rows = [
        "| dataset | expert | trajectories | return (mean +- std) | expert violation rate | violating kept | size |",
        "|---|---|---|---|---|---|---|",
    ]
    for path in sorted(pathlib.Path(directory).glob("*.npz")):
        metadata = load(path).metadata
        generation = metadata["generation"]
        rows.append(
            f"| {path.stem} | {metadata['expert']['algorithm']} | {metadata['n_trajectories']} | "
            f"{metadata['mean_return']:.2f} +- {metadata['std_return']:.2f} | "
            f"{generation['expert_violation_rate']:.0%} of {generation['expert_episodes']} | "
            f"{metadata['n_violating_trajectories']} | {path.stat().st_size / 1e3:.0f} kB |"
        )
    return "\n".join(rows)
