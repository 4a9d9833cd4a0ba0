"""
Demonstrations in the formats of other libraries, as optional extras (neither is imported by ``sb3_icrl.data``):

- ``imitation`` >= 1.0 (``pip install sb3-icrl[datasets]``): a HuggingFace ``datasets`` folder
  (``Dataset.save_to_disk``), one row per trajectory with the columns ``obs`` (``T + 1`` observations), ``acts``
  (``T``), ``infos`` (``T`` JSON strings, jsonpickle-compatible), ``terminal`` (bool) and ``rews`` (``T``). This is what
  ``imitation.data.serialize.save`` writes and ``imitation.data.serialize.load`` reads. The true costs travel in the
  infos (``info["cost"]``, as the benchmark envs report them), so that ``imitation`` reads the folder unchanged; our
  metadata goes into ``sb3_icrl.json`` inside the folder. :func:`~sb3_icrl.data.registry.load_demonstrations` loads
  such folders by path.
- Minari (``pip install sb3-icrl[minari]``): :func:`to_minari` writes a local Minari dataset, :func:`from_minari`
  reads one (local, or downloaded by Minari); the true costs are the step infos' ``cost`` (``(T + 1, n_costs)``: Minari
  keeps the reset info in row 0).

Without true costs in the data (``imitation`` or Minari data recorded elsewhere), ``missing_costs`` decides: raise
(``"error"``), or fill zeros and flag ``true_costs_known: false`` in the metadata, with a warning (``"warn"``, the
default) or without (``"zeros"``).
"""

import contextlib
import json
import os
import pathlib
import shutil
import tempfile
import warnings
from collections.abc import Iterator, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env import VecEnv

from sb3_icrl.data.checks import check_env_id
from sb3_icrl.data.importers import is_safe_global
from sb3_icrl.data.serialize import (
    DemonstrationError,
    check_imported_values,
    check_spaces,
    package_versions,
    trajectory_statistics,
)
from sb3_icrl.data.types import Demonstrations, Trajectory

#: Files ``datasets.Dataset.save_to_disk`` writes in every dataset folder
HF_DATASET_FILES = ("dataset_info.json", "state.json")
#: Our metadata inside an ``imitation`` dataset folder or a Minari dataset folder
METADATA_FILE = "sb3_icrl.json"
#: Columns of ``imitation``'s trajectory datasets
IMITATION_COLUMNS = ("obs", "acts", "infos", "terminal")
_MISSING_COSTS = ("error", "warn", "zeros")


def _import(module: str, extra: str) -> Any:
    try:
        return __import__(module)
    except ImportError as error:
        raise ImportError(f"This needs `{module}`: pip install 'sb3-icrl[{extra}]' ({error}).") from error


def is_imitation_dataset(path: str | os.PathLike) -> bool:
    """:return: Whether ``path`` is a folder written by ``datasets.Dataset.save_to_disk`` (``imitation`` >= 1.0)."""
    folder = pathlib.Path(path)
    return folder.is_dir() and all((folder / name).is_file() for name in HF_DATASET_FILES)


def _json_value(value: Any) -> Any:
    """JSON-friendly copy of an info value (numpy arrays and scalars become lists and numbers)."""
    if isinstance(value, dict):
        return {str(key): _json_value(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_value(item) for item in value]
    if isinstance(value, (np.ndarray, np.generic)):
        return value.tolist()
    return value


def _info_strings(trajectory: Trajectory, cost_info_key: str) -> list[str]:
    infos: Any = trajectory.infos if trajectory.infos is not None else [{} for _ in range(len(trajectory))]
    strings = []
    for info, cost in zip(infos, trajectory.costs, strict=True):
        entry = _json_value(dict(info))
        entry[cost_info_key] = _json_value(cost)
        try:
            strings.append(json.dumps(entry))
        except TypeError as error:
            raise DemonstrationError(
                f"An info dict cannot be written as JSON ({error}): drop the infos or simplify them."
            ) from error
    return strings


def _replace_folder(build: Any, path: pathlib.Path, overwrite: bool) -> None:
    """Write a folder with ``build(tmp)`` in a temporary folder beside ``path``, then move it to ``path``."""
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists: pass `overwrite=True` to replace it.")
    path.parent.mkdir(parents=True, exist_ok=True)
    staging = pathlib.Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
    try:
        build(staging)
        old = None
        if path.exists():
            old = pathlib.Path(tempfile.mkdtemp(prefix=f".{path.name}.old.", dir=path.parent))
            os.replace(path, old / path.name)
        os.replace(staging, path)
        if old is not None:
            shutil.rmtree(old)
    finally:
        if staging.exists():
            shutil.rmtree(staging)


def _write_json(path: pathlib.Path, content: dict[str, Any]) -> None:
    with open(path, "w") as file:
        json.dump(content, file, indent=2, sort_keys=True)
        file.write("\n")
        file.flush()
        os.fsync(file.fileno())


def save_imitation_dataset(
    path: str | os.PathLike,
    trajectories: Sequence[Trajectory],
    metadata: dict[str, Any] | None = None,
    cost_info_key: str = "cost",
    overwrite: bool = False,
) -> dict[str, Any]:
    """
    Write trajectories as an ``imitation`` >= 1.0 dataset folder (what ``imitation.data.serialize.save`` writes), the
    true costs in each step's ``info[cost_info_key]`` and our metadata in ``sb3_icrl.json``. The folder is built beside
    ``path`` and moved into place: a crash leaves no half-written dataset.

    :param path: The folder to write
    :param trajectories: At least one trajectory
    :param metadata: JSON-serialisable metadata (env id, expert, ...)
    :param cost_info_key: Info key of the true costs
    :param overwrite: Replace an existing folder
    :return: The metadata written
    """
    datasets = _import("datasets", "datasets")
    if len(trajectories) == 0:
        raise DemonstrationError("Nothing to save: the list of trajectories is empty.")
    columns = {
        "obs": [np.asarray(t.obs) for t in trajectories],
        "acts": [np.asarray(t.acts) for t in trajectories],
        "infos": [_info_strings(t, cost_info_key) for t in trajectories],
        "terminal": [bool(t.terminal) for t in trajectories],
        "rews": [np.asarray(t.rews) for t in trajectories],
    }
    content = dict(metadata or {})
    content.update(trajectory_statistics(trajectories))
    content.update({"format": "imitation-datasets", "cost_info_key": cost_info_key, "versions": package_versions()})
    try:
        json.dumps(content)
    except TypeError as error:
        raise DemonstrationError(f"The metadata must be JSON-serialisable: {error}.") from error

    def build(folder: pathlib.Path) -> None:
        with _quiet(datasets):
            datasets.Dataset.from_dict(columns).save_to_disk(os.fspath(folder))
        _write_json(folder / METADATA_FILE, content)

    _replace_folder(build, pathlib.Path(path), overwrite)
    return content


@contextlib.contextmanager
def _quiet(datasets: Any) -> Iterator[None]:
    """No progress bars from ``datasets`` (restored afterwards)."""
    is_disabled = getattr(datasets.utils, "are_progress_bars_disabled", None)
    if is_disabled is None:  # older datasets: leave the bars as they are
        yield
        return
    was_disabled = is_disabled()
    datasets.disable_progress_bars()
    try:
        yield
    finally:
        if not was_disabled:
            datasets.enable_progress_bars()


def _column_dtype(feature: Any) -> np.dtype | None:
    """The numpy dtype of the values of a (nested) sequence feature, ``None`` for strings and other non-numbers."""
    while hasattr(feature, "feature"):
        feature = feature.feature
    dtype = getattr(feature, "dtype", None)
    try:
        return np.dtype(dtype) if dtype not in (None, "string", "large_string") else None
    except TypeError:
        return None


def _costs_or_zeros(
    costs: np.ndarray | None, length: int, missing_costs: str, source: str, cost_info_key: str
) -> tuple[np.ndarray, bool]:
    if costs is not None:
        return costs, True
    if missing_costs == "error":
        raise DemonstrationError(
            f"{source} has no true costs (no {cost_info_key!r} in its infos). Pass `missing_costs='warn'` or 'zeros' to "
            "load it with zero costs (flagged `true_costs_known: false`), or the right `cost_info_key`."
        )
    return np.zeros(length, dtype=np.float32), False


def _check_missing_costs(missing_costs: str) -> None:
    if missing_costs not in _MISSING_COSTS:
        raise ValueError(f"`missing_costs` must be one of {_MISSING_COSTS}, got {missing_costs!r}.")


def _warn_missing_costs(source: str, n_missing: int, missing_costs: str, cost_info_key: str) -> None:
    if n_missing and missing_costs == "warn":
        warnings.warn(
            f"{source}: {n_missing} trajectories have no true costs ({cost_info_key!r} in their infos); their costs are "
            "zeros (`true_costs_known: false` in the metadata): violation statistics of this data mean nothing.",
            stacklevel=3,
        )


#: jsonpickle tags whose value names a Python object to import (``py/repr`` and ``py/mod`` are never accepted)
_JSONPICKLE_NAME_TAGS = ("py/object", "py/type", "py/function")


def _check_jsonpickle_names(content: Any, source: str) -> None:
    """Refuse jsonpickle content that names anything but numpy's array and scalar builders or plain containers."""
    if isinstance(content, list):
        for item in content:
            _check_jsonpickle_names(item, source)
    if not isinstance(content, dict):
        return
    for key, value in content.items():
        if key in ("py/repr", "py/mod") or (
            key in _JSONPICKLE_NAME_TAGS and not (isinstance(value, str) and is_safe_global(*value.rpartition(".")[::2]))
        ):
            raise DemonstrationError(
                f"{source}: refusing an info that names {value!r} ({key}): only numpy arrays, numpy scalars and plain "
                "containers are read from jsonpickle infos."
            )
        _check_jsonpickle_names(value, source)


def _decode_info(text: str, source: str) -> dict[str, Any]:
    try:
        info = json.loads(text)
    except json.JSONDecodeError as error:
        raise DemonstrationError(f"{source}: an info is not JSON ({error}).") from error
    if any(isinstance(value, dict) and any(str(key).startswith("py/") for key in value) for value in info.values()):
        # jsonpickle tags (numpy values written by imitation): decode them with jsonpickle itself, once they are known
        # to name nothing but numpy's array and scalar builders (jsonpickle calls what a file names)
        _check_jsonpickle_names(info, source)
        try:
            import jsonpickle  # type: ignore[import-untyped]
        except ImportError as error:
            raise DemonstrationError(
                f"{source}: the infos hold jsonpickle-encoded objects; pip install 'sb3-icrl[datasets]' (or jsonpickle) "
                "to read them."
            ) from error
        with warnings.catch_warnings():
            # (jsonpickle 4.1 warns of its 5.0 default on every call; keys=False reads what imitation writes)
            warnings.filterwarnings("ignore", message="keys will default", category=DeprecationWarning)
            info = jsonpickle.decode(text, keys=False)
    return info if isinstance(info, dict) else {"value": info}


def load_imitation_dataset(
    path: str | os.PathLike,
    env: gym.Env | VecEnv | str | None = None,
    cost_info_key: str = "cost",
    missing_costs: str = "warn",
    load_infos: bool = False,
    allow_env_mismatch: bool = False,
) -> Demonstrations:
    """
    Read an ``imitation`` >= 1.0 dataset folder (``imitation.data.serialize.save``, or :func:`save_imitation_dataset`).

    :param path: The folder
    :param env: Optional target env: the data must fit its spaces, and its id match the recorded one (when recorded)
    :param cost_info_key: Info key of the true per-step cost
    :param missing_costs: Trajectories without costs: ``"error"``, ``"warn"`` (zeros, flagged, warning) or ``"zeros"``
    :param load_infos: Keep the decoded infos (otherwise ``infos`` is ``None``, as for ``.npz`` files)
    :param allow_env_mismatch: With ``env``: accept data recorded on another env id whose spaces fit
    :return: The trajectories; the metadata of ``sb3_icrl.json`` when present, with ``true_costs_known``
    """
    datasets = _import("datasets", "datasets")
    _check_missing_costs(missing_costs)
    folder = pathlib.Path(path)
    if not is_imitation_dataset(folder):
        raise DemonstrationError(
            f"{folder} is not a HuggingFace dataset folder (it lacks {list(HF_DATASET_FILES)}): imitation >= 1.0 writes "
            "those with `imitation.data.serialize.save`; older files are `.npz` (convert them with `from_imitation`)."
        )
    with _quiet(datasets):
        dataset = datasets.load_from_disk(os.fspath(folder))
    if isinstance(dataset, datasets.DatasetDict):
        raise DemonstrationError(f"{folder} holds several splits ({list(dataset)}); imitation writes a single dataset.")
    missing = [column for column in (*IMITATION_COLUMNS, "rews") if column not in dataset.column_names]
    if missing:
        raise DemonstrationError(
            f"{folder} lacks the columns {missing} (has {dataset.column_names}): imitation's trajectory datasets hold "
            f"{[*IMITATION_COLUMNS, 'rews']} (sb3-icrl needs rewards: `TrajectoryWithRew`)."
        )
    metadata_file = folder / METADATA_FILE
    metadata: dict[str, Any] = json.loads(metadata_file.read_text()) if metadata_file.is_file() else {}
    if env is not None and not allow_env_mismatch:
        check_env_id(metadata, env)
    dtypes = {column: _column_dtype(dataset.features[column]) for column in ("obs", "acts", "rews")}
    trajectories, n_missing = [], 0
    for index in range(len(dataset)):
        row = dataset[index]
        source = f"{folder} trajectory {index}"
        infos = [_decode_info(text, source) for text in row["infos"]]
        has_costs = len(infos) > 0 and all(cost_info_key in info for info in infos)
        recorded = np.asarray([info[cost_info_key] for info in infos], dtype=np.float32) if has_costs else None
        costs, known = _costs_or_zeros(recorded, len(infos), missing_costs, source, cost_info_key)
        n_missing += not known
        rews = np.asarray(row["rews"], dtype=dtypes["rews"])
        try:
            trajectories.append(
                Trajectory(
                    obs=np.asarray(row["obs"], dtype=dtypes["obs"]),
                    acts=np.asarray(row["acts"], dtype=dtypes["acts"]),
                    infos=np.array(infos, dtype=object) if load_infos else None,
                    terminal=bool(row["terminal"]),
                    rews=rews if rews.dtype.kind == "f" else rews.astype(np.float32),
                    costs=costs,
                )
            )
        except ValueError as error:
            raise DemonstrationError(f"{source}: {error}") from error
        check_imported_values(trajectories[-1], source)
    if not trajectories:
        raise DemonstrationError(f"{folder} holds no trajectories.")
    _warn_missing_costs(str(folder), n_missing, missing_costs, cost_info_key)
    metadata["true_costs_known"] = bool(metadata.get("true_costs_known", True)) and n_missing == 0
    demonstrations = Demonstrations(trajectories, metadata)
    if env is not None:
        transitions = demonstrations.transitions
        check_spaces(transitions.obs, transitions.acts, env)
    return demonstrations


def to_minari(
    demonstrations: Demonstrations | Sequence[Trajectory],
    dataset_id: str,
    env: str | gym.Env | None = None,
    cost_info_key: str = "cost",
    overwrite: bool = False,
    **kwargs: Any,
) -> Any:
    """
    Write demonstrations as a local Minari dataset (under ``MINARI_DATASETS_PATH``, default ``~/.minari/datasets``).

    Each trajectory becomes an episode: ``observations`` (``T + 1``), ``actions``, ``rewards``, ``terminations`` (the
    last step when the trajectory is ``terminal``), ``truncations`` (the last step otherwise) and the infos'
    ``cost_info_key`` (``(T + 1, n_costs)``, row 0 for the reset). Our metadata goes into ``sb3_icrl.json`` in the
    dataset's folder.

    :param demonstrations: The demonstrations
    :param dataset_id: Minari id, ``namespace/name-v0`` or ``name-v0``
    :param env: The env (or id) they were recorded on; default: the metadata's ``env_id``
    :param cost_info_key: Info key of the costs
    :param overwrite: Replace a local dataset with that id
    :param kwargs: More arguments of ``minari.create_dataset_from_buffers`` (``author``, ``description``, ...)
    :return: The ``MinariDataset``
    """
    minari = _import("minari", "minari")
    from minari.storage import get_dataset_path

    trajectories = list(demonstrations)
    if not trajectories:
        raise DemonstrationError("Nothing to save: the list of trajectories is empty.")
    metadata = dict(demonstrations.metadata) if isinstance(demonstrations, Demonstrations) else {}
    env = env if env is not None else metadata.get("env_id")
    if env is None:
        raise DemonstrationError("Minari datasets record their env: pass `env=` (the metadata has no `env_id`).")
    folder = _minari_dataset_folder(dataset_id, get_dataset_path)
    if folder.exists():
        if not overwrite:
            raise FileExistsError(f"A local Minari dataset {dataset_id!r} exists: pass `overwrite=True` to replace it.")
        nested = sorted(path.name for path in folder.iterdir() if path.is_dir() and path.name != "data")
        if nested:
            raise DemonstrationError(
                f"{folder} holds other folders ({', '.join(nested)}): a namespace of other datasets, not one dataset. "
                "Nothing was deleted: choose another id."
            )
        # (a folder Minari does not list, left half-written by a failed write, goes too)
        shutil.rmtree(folder)
    try:
        return _write_minari(minari, trajectories, metadata, dataset_id, env, cost_info_key, kwargs, folder)
    except BaseException:
        # A half-written dataset would block its id: Minari refuses to write over it and does not list it to delete
        shutil.rmtree(folder, ignore_errors=True)
        raise


def _minari_dataset_folder(dataset_id: str, get_dataset_path: Any) -> pathlib.Path:
    """
    The folder of a local Minari dataset; an id that is not ``(namespace/)name-v<N>``, or that names a folder outside
    the datasets' root, is refused (the folder may be deleted: it must be one dataset's own).
    """
    from minari.dataset.minari_dataset import parse_dataset_id

    root = pathlib.Path(get_dataset_path()).resolve()
    folder = pathlib.Path(get_dataset_path(dataset_id)).resolve()
    try:
        parse_dataset_id(dataset_id)
        well_formed = root in folder.parents
    except (TypeError, ValueError):
        well_formed = False
    if not well_formed:
        raise DemonstrationError(
            f"{dataset_id!r} is not a Minari dataset id: use `namespace/name-v0` or `name-v0` (a version is required)."
        )
    return folder


def _write_minari(
    minari: Any,
    trajectories: list[Trajectory],
    metadata: dict[str, Any],
    dataset_id: str,
    env: str | gym.Env,
    cost_info_key: str,
    kwargs: dict[str, Any],
    folder: pathlib.Path,
) -> Any:
    """The body of :func:`to_minari`, once the id is free: the episodes, then our metadata beside them."""
    from minari.data_collector import EpisodeBuffer

    buffers = []
    for index, trajectory in enumerate(trajectories):
        length = len(trajectory)
        costs = np.asarray(trajectory.costs, dtype=np.float32).reshape(length, -1)
        end = np.zeros(length, dtype=bool)
        end[-1] = True
        buffers.append(
            EpisodeBuffer(
                id=index,
                observations=np.asarray(trajectory.obs),
                actions=np.asarray(trajectory.acts),
                rewards=list(np.asarray(trajectory.rews, dtype=np.float64)),
                terminations=list(end & trajectory.terminal),
                truncations=list(end & (not trajectory.terminal)),
                # Minari's infos have a row for the reset; 2-D so that its arrow storage reads them back
                infos={cost_info_key: np.concatenate([np.zeros((1, costs.shape[1]), dtype=np.float32), costs])},
            )
        )
    kwargs.setdefault("data_format", "arrow")
    kwargs.setdefault("algorithm_name", str(metadata.get("expert", {}).get("algorithm", "unknown")))
    kwargs.setdefault("description", f"Expert demonstrations with true costs in infos[{cost_info_key!r}] (sb3-icrl)")
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*(author|description|eval_env|code_permalink).*")
        dataset = minari.create_dataset_from_buffers(dataset_id, buffers, env=env, **kwargs)
    content = dict(metadata)
    content.update(trajectory_statistics(trajectories))
    content.update({"format": "minari", "cost_info_key": cost_info_key, "versions": package_versions()})
    if "env_id" not in content and isinstance(env, str):
        content["env_id"] = env
    _write_json(folder / METADATA_FILE, content)
    return dataset


def from_minari(
    dataset: Any,
    cost_info_key: str = "cost",
    missing_costs: str = "warn",
    download: bool = False,
) -> Demonstrations:
    """
    Read a Minari dataset.

    :param dataset: A ``MinariDataset`` or a dataset id
    :param cost_info_key: Info key of the true per-step cost
    :param missing_costs: Episodes without costs: ``"error"``, ``"warn"`` (zeros, flagged, warning) or ``"zeros"``
    :param download: Let Minari download a dataset id not found locally
    :return: The demonstrations; the metadata has the env id (from the dataset's env spec) and ``true_costs_known``
    """
    minari = _import("minari", "minari")
    _check_missing_costs(missing_costs)
    if isinstance(dataset, str):
        dataset_id = dataset
        try:
            dataset = minari.load_dataset(dataset_id, download=download)
        except (FileNotFoundError, ValueError) as error:
            raise DemonstrationError(
                f"No Minari dataset {dataset_id!r} ({error}). Local ones: {minari.list_local_datasets()}."
            ) from error
    from minari.storage import get_dataset_path

    dataset_id = dataset.spec.dataset_id
    metadata_file = pathlib.Path(get_dataset_path(dataset_id)) / METADATA_FILE
    metadata: dict[str, Any] = json.loads(metadata_file.read_text()) if metadata_file.is_file() else {}
    env_spec = dataset.spec.env_spec
    if env_spec is not None:
        metadata.setdefault("env_id", env_spec.id)
    metadata.setdefault("source", {"format": "minari", "dataset_id": dataset_id})
    trajectories, n_missing = [], 0
    for episode in dataset.iterate_episodes():
        source = f"Minari dataset {dataset_id!r} episode {episode.id}"
        if not isinstance(episode.observations, np.ndarray) or not isinstance(episode.actions, np.ndarray):
            raise DemonstrationError(f"{source}: dict or tuple observations and actions are not supported.")
        length = len(episode.rewards)
        recorded = episode.infos.get(cost_info_key)
        costs_in_data = None
        if recorded is not None:
            values = np.asarray(recorded, dtype=np.float32)
            # one row per step after the reset row; a single cost per step comes back as (T, 1)
            values = values[1:] if len(values) == length + 1 else values
            costs_in_data = values[:, 0] if values.ndim == 2 and values.shape[1] == 1 else values
        costs, known = _costs_or_zeros(costs_in_data, length, missing_costs, source, cost_info_key)
        n_missing += not known
        rewards = np.asarray(episode.rewards)
        try:
            trajectories.append(
                Trajectory(
                    obs=episode.observations,
                    acts=episode.actions,
                    infos=None,
                    terminal=bool(np.asarray(episode.terminations)[-1]),
                    rews=rewards if rewards.dtype.kind == "f" else rewards.astype(np.float32),
                    costs=costs,
                )
            )
        except ValueError as error:
            raise DemonstrationError(f"{source}: {error}") from error
        check_imported_values(trajectories[-1], source)
    if not trajectories:
        raise DemonstrationError(f"Minari dataset {dataset_id!r} holds no episodes.")
    _warn_missing_costs(f"Minari dataset {dataset_id!r}", n_missing, missing_costs, cost_info_key)
    metadata["true_costs_known"] = bool(metadata.get("true_costs_known", True)) and n_missing == 0
    return Demonstrations(trajectories, metadata)
