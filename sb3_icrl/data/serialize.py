"""
Save and load demonstrations: an ``.npz`` archive in the layout ``imitation.data.serialize.load`` reads, plus a
JSON sidecar with the metadata and the archive's sha256.

Archive keys (``N`` transitions in ``n`` trajectories of lengths ``T_1..T_n``):

============  ======================================  ==============================================
key           shape                                   content
============  ======================================  ==============================================
``obs``       ``(N + n,) + obs_shape``                each trajectory's ``T_i + 1`` observations, in order
``acts``      ``(N,) + action_shape``                 actions
``infos``     ``(N,)`` object array of dicts          for ``imitation`` only (pickled); sb3-icrl never reads it by default
``terminal``  ``(n,)`` bool                           whether each trajectory ended in a terminal state
``rews``      ``(N,)`` float                          rewards
``indices``   ``(n - 1,)`` int                        ``cumsum(T)[:-1]``: where ``acts`` splits into trajectories
``costs``     ``(N,)`` or ``(N, n_costs)`` float      true costs (an extra key ``imitation`` ignores)
============  ======================================  ==============================================

``obs`` splits at ``indices + arange(n - 1) + 1`` (one extra observation per trajectory), as ``imitation`` does.
Everything but ``infos`` is a plain numeric array: :func:`load` reads with ``allow_pickle=False``.

The archive is written with fixed zip timestamps, so the same trajectories give the same bytes (and checksum).
"""

import hashlib
import importlib.metadata
import io
import itertools
import json
import os
import pathlib
import platform
import zipfile
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env import VecEnv

from sb3_icrl.common.utils import atomic_write_bytes
from sb3_icrl.data.types import Demonstrations, Trajectory
from sb3_icrl.envs import NAMESPACE

#: Version of the file layout, stored in the sidecar
FORMAT_VERSION = 1
#: Keys every archive must hold (``imitation``'s keys plus ``costs``)
REQUIRED_KEYS = ("obs", "acts", "infos", "terminal", "rews", "indices", "costs")
#: Packages whose versions go into the sidecar
_VERSIONED_PACKAGES = ("sb3-icrl", "numpy", "gymnasium", "stable-baselines3", "torch", "mujoco")
# Bounds checks tolerate float32 round-off of values stored as float64 and vice versa
_BOUNDS_TOLERANCE = 1e-5


class DemonstrationError(ValueError):
    """A demonstration file or dataset that cannot be used as it is; the message says what is wrong and how to fix it."""


def metadata_path(path: str | os.PathLike) -> pathlib.Path:
    """
    :param path: The ``.npz`` archive
    :return: Its JSON sidecar: ``name.npz`` -> ``name.json`` (other names get ``.json`` appended)
    """
    path = pathlib.Path(path)
    return path.with_suffix(".json") if path.suffix == ".npz" else path.with_name(path.name + ".json")


def package_versions() -> dict[str, str | None]:
    """Versions of Python and of the packages that shape the data (``None`` where not installed)."""
    versions: dict[str, str | None] = {"python": platform.python_version()}
    for package in _VERSIONED_PACKAGES:
        try:
            versions[package] = importlib.metadata.version(package)
        except importlib.metadata.PackageNotFoundError:
            versions[package] = None
    return versions


def _npz_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    # np.savez stamps each member with the current time; a fixed date makes the bytes reproducible
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for key, array in arrays.items():
            member = zipfile.ZipInfo(f"{key}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            member.compress_type = zipfile.ZIP_DEFLATED
            with archive.open(member, "w", force_zip64=True) as file:
                np.lib.format.write_array(file, np.asanyarray(array), allow_pickle=array.dtype == object)
    return buffer.getvalue()


def _common_layout(trajectories: Sequence[Trajectory], field: str) -> tuple[np.dtype, tuple[int, ...]]:
    layouts = {(getattr(t, field).dtype, getattr(t, field).shape[1:]) for t in trajectories}
    if len(layouts) != 1:
        raise DemonstrationError(
            f"All trajectories must share the dtype and per-step shape of `{field}`, got {sorted(map(str, layouts))}: "
            "cast them to one dtype before saving."
        )
    return layouts.pop()


def trajectory_statistics(trajectories: Sequence[Trajectory]) -> dict[str, Any]:
    """
    Per-episode statistics stored in the sidecar.

    :param trajectories: The trajectories
    :return: Counts, per-episode returns, costs, lengths, and the violation statistics against the true cost
    """
    violations = [t.violates for t in trajectories]
    returns = [t.episode_return for t in trajectories]
    return {
        "n_trajectories": len(trajectories),
        "n_transitions": int(sum(len(t) for t in trajectories)),
        "episode_returns": returns,
        "episode_costs": [t.episode_cost for t in trajectories],
        "episode_lengths": [len(t) for t in trajectories],
        "mean_return": float(np.mean(returns)),
        "std_return": float(np.std(returns)),
        "n_violating_trajectories": int(sum(violations)),
        "violating_share": float(np.mean(violations)),
        "n_violating_steps": int(sum(int(t.step_violations.sum()) for t in trajectories)),
    }


def save(
    path: str | os.PathLike, trajectories: Sequence[Trajectory], metadata: dict[str, Any] | None = None
) -> dict[str, Any]:
    """
    Write trajectories to ``path`` (``.npz``) and the metadata to its JSON sidecar (:func:`metadata_path`), atomically.

    The sidecar holds ``metadata`` (env id and kwargs, expert, seed: whatever the caller knows) plus what is
    computed here: statistics (:func:`trajectory_statistics`), shapes and dtypes, package versions and the
    archive's ``sha256``.

    :param path: Destination archive, e.g. ``"demos/GridWorldWall-v0.npz"``
    :param trajectories: At least one trajectory; all with the same dtypes and per-step shapes
    :param metadata: JSON-serialisable metadata to store with them
    :return: The sidecar's content
    """
    if len(trajectories) == 0:
        raise DemonstrationError("Nothing to save: the list of trajectories is empty.")
    layouts = {field: _common_layout(trajectories, field) for field in ("obs", "acts", "rews", "costs")}
    lengths = [len(t) for t in trajectories]
    # Like imitation: missing infos become empty dicts, so that its loader can split the key
    infos = [t.infos if t.infos is not None else np.array([{} for _ in range(len(t))], dtype=object) for t in trajectories]
    arrays = {
        "obs": np.concatenate([t.obs for t in trajectories]),
        "acts": np.concatenate([t.acts for t in trajectories]),
        "infos": np.concatenate([np.asarray(i, dtype=object) for i in infos]),
        "terminal": np.array([bool(t.terminal) for t in trajectories], dtype=bool),
        "rews": np.concatenate([t.rews for t in trajectories]),
        "indices": np.cumsum(lengths[:-1], dtype=np.int64),
        "costs": np.concatenate([t.costs for t in trajectories]),
    }
    for key in ("obs", "acts", "rews", "costs"):
        # load() refuses such a file: refuse to write it
        _check_finite(key, arrays[key], f"Cannot save the trajectories to {os.fspath(path)}")
    if np.any(arrays["costs"] < 0):
        raise DemonstrationError(
            f"Cannot save the trajectories to {os.fspath(path)}: `costs` holds negative values (min "
            f"{float(arrays['costs'].min()):g}); a true cost counts violations and must be >= 0."
        )
    content = _npz_bytes(arrays)
    sidecar = dict(metadata or {})
    sidecar.update(trajectory_statistics(trajectories))
    sidecar.update(
        {
            "format_version": FORMAT_VERSION,
            "layout": {field: {"dtype": str(dtype), "shape": list(shape)} for field, (dtype, shape) in layouts.items()},
            "versions": package_versions(),
            "sha256": hashlib.sha256(content).hexdigest(),
        }
    )
    try:
        json.dumps(sidecar)
    except TypeError as error:
        raise DemonstrationError(f"The metadata must be JSON-serialisable: {error}.") from error
    path = pathlib.Path(path)
    # Archive first: a crash before the sidecar is written shows up as a checksum mismatch, not as silent bad data
    atomic_write_bytes(path, content)
    atomic_write_bytes(metadata_path(path), (json.dumps(sidecar, indent=2, sort_keys=True) + "\n").encode())
    return sidecar


def _read_metadata(path: pathlib.Path, require_metadata: bool) -> dict[str, Any] | None:
    sidecar = metadata_path(path)
    if not sidecar.is_file():
        if require_metadata:
            raise DemonstrationError(
                f"{path} has no metadata sidecar {sidecar.name} (env, expert, checksum). Regenerate the file with "
                "`python -m sb3_icrl.data generate ...`, or pass `require_metadata=False` to load it unchecked."
            )
        return None
    try:
        with open(sidecar) as file:
            metadata = json.load(file)
    except json.JSONDecodeError as error:
        raise DemonstrationError(
            f"The metadata sidecar {sidecar} is not valid JSON ({error}): regenerate the dataset."
        ) from error
    if not isinstance(metadata, dict):
        raise DemonstrationError(f"The metadata sidecar {sidecar} must hold a JSON object, got {type(metadata).__name__}.")
    return metadata


def _check_dtype(key: str, array: np.ndarray, kinds: str, what: str, source: str) -> None:
    if array.dtype.kind not in kinds:
        raise DemonstrationError(f"{source}: `{key}` must be {what}, got dtype {array.dtype}.")


def _check_finite(key: str, array: np.ndarray, source: str) -> None:
    if array.dtype.kind == "f" and not np.all(np.isfinite(array)):
        bad = np.argwhere(~np.isfinite(array.reshape(len(array), -1)).all(axis=1)).ravel()
        raise DemonstrationError(
            f"{source}: `{key}` holds NaN or infinite values ({len(bad)} rows, first at row {int(bad[0])}): "
            "drop the broken trajectories and regenerate the file."
        )


def check_imported_values(trajectory: Trajectory, source: str) -> None:
    """
    Refuse an imported trajectory whose numbers :func:`save` and :func:`load` would refuse later, far from the data:
    NaN or infinite observations, actions, rewards or costs, and negative costs.

    :param trajectory: The trajectory as an importer built it
    :param source: Where it came from (file, episode), for the message
    :raises DemonstrationError: Naming the field, the first bad step and the fix
    """
    for key in ("obs", "acts", "rews", "costs"):
        array = np.asarray(getattr(trajectory, key))
        if array.dtype.kind not in "biuf":
            raise DemonstrationError(f"{source}: `{key}` must be numbers, got dtype {array.dtype}.")
        bad = ~np.isfinite(array.reshape(len(array), -1)).all(axis=1) if array.dtype.kind == "f" else np.zeros(0, bool)
        if bad.any():
            raise DemonstrationError(
                f"{source}: `{key}` holds NaN or infinite values ({int(bad.sum())} rows, first at row "
                f"{int(np.argmax(bad))}): repair or drop those steps in the source data before importing it."
            )
    if np.any(np.asarray(trajectory.costs) < 0):
        raise DemonstrationError(
            f"{source}: `costs` holds negative values (min {float(np.min(trajectory.costs)):g}); a true cost counts "
            "violations and must be >= 0."
        )


def _validate_arrays(arrays: dict[str, np.ndarray], source: str) -> np.ndarray:
    """Check dtypes, shapes and values; return the boundaries of the trajectories in ``acts`` (``[0, ..., N]``)."""
    _check_dtype("obs", arrays["obs"], "biuf", "a numeric array", source)
    _check_dtype("acts", arrays["acts"], "biuf", "a numeric array", source)
    _check_dtype("rews", arrays["rews"], "f", "a float array", source)
    _check_dtype("costs", arrays["costs"], "f", "a float array (the true cost of each step)", source)
    _check_dtype("terminal", arrays["terminal"], "b", "a bool array (one per trajectory)", source)
    _check_dtype("indices", arrays["indices"], "iu", "an integer array", source)
    acts, indices = arrays["acts"], arrays["indices"]
    n_transitions = len(acts)
    if n_transitions == 0:
        raise DemonstrationError(f"{source}: the dataset is empty (no actions): generate at least one trajectory.")
    if indices.ndim != 1:
        raise DemonstrationError(f"{source}: `indices` must be 1-D (where `acts` splits), got shape {indices.shape}.")
    bounds = np.concatenate([[0], indices.astype(np.int64), [n_transitions]])
    if np.any(np.diff(bounds) < 1):
        raise DemonstrationError(
            f"{source}: `indices` must increase strictly within (0, {n_transitions}) (every trajectory has at least one "
            f"action), got {indices.tolist()[:10]}."
        )
    n_trajectories = len(bounds) - 1
    expected = {
        "obs": n_transitions + n_trajectories,
        "rews": n_transitions,
        "costs": n_transitions,
        "terminal": n_trajectories,
    }
    for key, rows in expected.items():
        if len(arrays[key]) != rows:
            raise DemonstrationError(
                f"{source}: `{key}` has {len(arrays[key])} rows, expected {rows} for {n_trajectories} trajectories of "
                f"{n_transitions} actions in all (`obs` has one extra row per trajectory)."
            )
    if arrays["rews"].ndim != 1 or arrays["terminal"].ndim != 1:
        raise DemonstrationError(
            f"{source}: `rews` and `terminal` must be 1-D, got shapes {arrays['rews'].shape} and {arrays['terminal'].shape}."
        )
    if arrays["costs"].ndim not in (1, 2):
        raise DemonstrationError(f"{source}: `costs` must have shape (N,) or (N, n_costs), got {arrays['costs'].shape}.")
    for key in ("obs", "acts", "rews", "costs"):
        _check_finite(key, arrays[key], source)
    return bounds


def _read_arrays(content: bytes, source: str) -> dict[str, np.ndarray]:
    try:
        archive = np.load(io.BytesIO(content), allow_pickle=False)
    except (ValueError, OSError, zipfile.BadZipFile) as error:
        raise DemonstrationError(f"{source} is not an .npz archive ({error}).") from error
    if not isinstance(archive, np.lib.npyio.NpzFile):
        raise DemonstrationError(f"{source} holds a single array, not an .npz archive of demonstrations.")
    with archive:
        missing = [key for key in REQUIRED_KEYS if key not in archive.files]
        if missing:
            raise DemonstrationError(
                f"{source} lacks the keys {missing} (has {sorted(archive.files)}); a demonstration archive holds "
                f"{list(REQUIRED_KEYS)}. Files written by imitation have no `costs`: convert them with `from_imitation`."
            )
        arrays = {}
        for key in REQUIRED_KEYS:
            if key == "infos":  # pickled objects: only read on request
                continue
            try:
                arrays[key] = archive[key]
            except ValueError as error:
                raise DemonstrationError(
                    f"{source}: `{key}` is stored as pickled Python objects; it must be a plain numeric array ({error})."
                ) from error
    return arrays


def _read_infos(content: bytes, source: str) -> np.ndarray:
    # Unpickling runs code from the file: only on request, for files you trust
    with np.load(io.BytesIO(content), allow_pickle=True) as archive:
        infos = archive["infos"]
    if infos.ndim != 1:
        raise DemonstrationError(f"{source}: `infos` must be a 1-D array of dicts, got shape {infos.shape}.")
    return infos


def load(
    path: str | os.PathLike,
    env: gym.Env | VecEnv | str | None = None,
    verify_checksum: bool = True,
    require_metadata: bool = True,
    load_infos: bool = False,
    allow_env_mismatch: bool = False,
) -> Demonstrations:
    """
    Load and validate demonstrations written by :func:`save`.

    Raises :class:`DemonstrationError` on: a missing file or sidecar, a checksum mismatch, missing keys, wrong
    dtypes or shapes, NaNs, an empty dataset, and (with ``env``) observations or actions outside its spaces.

    :param path: The ``.npz`` archive
    :param env: Optional target environment (gymnasium env, VecEnv or registered id) whose spaces the data must fit
    :param verify_checksum: Compare the archive's sha256 with the sidecar's
    :param require_metadata: Refuse an archive without its JSON sidecar
    :param load_infos: Also read ``infos`` (unpickles objects: only for files you trust); otherwise ``infos`` is ``None``
    :param allow_env_mismatch: With ``env``: accept data whose sidecar names another env id (the spaces must still fit)
    :return: The trajectories and the sidecar's metadata
    """
    path = pathlib.Path(path)
    if not path.is_file():
        raise DemonstrationError(f"No demonstration file at {path}.")
    metadata = _read_metadata(path, require_metadata)
    content = path.read_bytes()
    if verify_checksum and metadata is not None:
        expected, actual = metadata.get("sha256"), hashlib.sha256(content).hexdigest()
        if expected != actual:
            raise DemonstrationError(
                f"Checksum mismatch for {path}: the sidecar records sha256 {expected}, the file has {actual}. The file "
                "was modified or only partly written: regenerate it (or pass `verify_checksum=False` to load it anyway)."
            )
    source = str(path)
    arrays = _read_arrays(content, source)
    bounds = _validate_arrays(arrays, source)
    infos = _read_infos(content, source) if load_infos else None
    if infos is not None and len(infos) != len(arrays["acts"]):
        raise DemonstrationError(
            f"{source}: `infos` has {len(infos)} entries, expected one per action ({len(arrays['acts'])})."
        )
    if env is not None:
        check_spaces(arrays["obs"], arrays["acts"], env, metadata, allow_env_mismatch)
    trajectories = []
    for index, (start, end) in enumerate(itertools.pairwise(bounds)):
        trajectories.append(
            Trajectory(
                obs=arrays["obs"][start + index : end + index + 1],
                acts=arrays["acts"][start:end],
                infos=None if infos is None else infos[start:end],
                terminal=bool(arrays["terminal"][index]),
                rews=arrays["rews"][start:end],
                costs=arrays["costs"][start:end],
            )
        )
    return Demonstrations(trajectories, metadata)


def _space_mismatch(name: str, data: np.ndarray, space: spaces.Space) -> str | None:
    """Why ``data`` (one row per step) does not fit ``space``, or ``None`` when it does."""
    if isinstance(space, spaces.Discrete):
        if data.ndim != 1 or data.dtype.kind not in "biu":
            return f"{name} are {data.dtype} of shape {data.shape[1:]} per step; {space} takes integer scalars"
        low, high = int(data.min()), int(data.max())
        if low < space.start or high >= space.start + space.n:
            return f"{name} range over [{low}, {high}], outside {space}"
        return None
    if isinstance(space, spaces.Box):
        if data.shape[1:] != space.shape:
            return f"{name} have shape {data.shape[1:]} per step; {space} expects {space.shape}"
        if not np.can_cast(data.dtype, space.dtype, casting="same_kind"):
            return f"{name} are {data.dtype}; {space} holds {space.dtype}"
        if data.dtype.kind == "f" and not np.all(np.isfinite(data)):
            return f"{int(np.sum(~np.isfinite(data)))} values of the {name} are NaN or infinite"
        inside = (data >= space.low - _BOUNDS_TOLERANCE) & (data <= space.high + _BOUNDS_TOLERANCE)
        if not np.all(inside):
            return f"{int(np.sum(~inside))} values of the {name} lie outside the bounds of {space}"
        return None
    shape = space.shape or ()
    if data.shape[1:] != shape or not all(space.contains(row.astype(space.dtype)) for row in data):
        return f"{name} do not all lie in {space}"
    return None


def _env_id(env: Any) -> str | None:
    """The registered id of a gymnasium env, a VecEnv's first env or an id (``None`` when it has none)."""
    if isinstance(env, str):
        return env
    try:
        spec = env.get_attr("spec", indices=[0])[0] if isinstance(env, VecEnv) else getattr(env, "spec", None)
    except (AttributeError, IndexError):
        return None
    return getattr(spec, "id", None)


def _same_env(first: str, second: str) -> bool:
    prefix = f"{NAMESPACE}/"
    return first.removeprefix(prefix) == second.removeprefix(prefix)


def check_spaces(
    obs: np.ndarray,
    acts: np.ndarray,
    env: gym.Env | VecEnv | str,
    metadata: dict[str, Any] | None = None,
    allow_env_mismatch: bool = False,
) -> None:
    """
    Check that observations and actions fit the spaces of ``env``, and that the data was recorded on it.

    :param obs: Observations, one row per step
    :param acts: Actions, one row per step
    :param env: A gymnasium env, a VecEnv or a registered id
    :param metadata: The dataset's metadata: its ``env_id`` must be the env's id (and goes into error messages)
    :param allow_env_mismatch: Accept data recorded on another env id whose spaces fit (e.g. a variant you registered)
    """
    recorded = (metadata or {}).get("env_id")
    if isinstance(env, str):
        made = gym.make(env)
        observation_space, action_space = made.observation_space, made.action_space
        made.close()
    else:
        observation_space, action_space = env.observation_space, env.action_space
    for name, data, space in (("observations", obs, observation_space), ("actions", acts, action_space)):
        problem = _space_mismatch(name, data, space)
        if problem is not None:
            origin = f" (the data was recorded on {recorded!r})" if recorded else ""
            raise DemonstrationError(
                f"The demonstrations do not match the target env: {problem}{origin}. Load the dataset made for this env."
            )
    target = _env_id(env)
    # Only a registered id names another env (some files carry a free-form label)
    registered = bool(recorded) and (str(recorded) in gym.registry or f"{NAMESPACE}/{recorded}" in gym.registry)
    if registered and target and not allow_env_mismatch and not _same_env(str(recorded), target):
        # Same shapes, another env (GridWorldWall-v0 data on GridWorldSquare-v0): the expert avoided another constraint
        raise DemonstrationError(
            f"The demonstrations were recorded on {recorded!r}, not on the target env {target!r}: load the dataset made "
            "for this env, or pass `allow_env_mismatch=True` (train.py: --allow-env-mismatch) if the data is meant for it."
        )


def from_imitation(
    trajectories: Sequence[Any],
    costs: Sequence[np.ndarray] | None = None,
    cost_info_key: str = "cost",
) -> list[Trajectory]:
    """
    Convert ``imitation`` trajectories (``TrajectoryWithRew`` or anything with ``obs``, ``acts``, ``infos``,
    ``terminal`` and ``rews``; ``imitation`` is not imported) to :class:`Trajectory`.

    The true costs come from ``costs`` when given, otherwise from ``info[cost_info_key]`` of every step.

    :param trajectories: The trajectories
    :param costs: Optional true costs, one array per trajectory (``(T,)`` or ``(T, n_costs)``)
    :param cost_info_key: Info key of the true per-step cost, used when ``costs`` is ``None``
    :return: The converted trajectories
    """
    if costs is not None and len(costs) != len(trajectories):
        raise DemonstrationError(
            f"`costs` has {len(costs)} arrays for {len(trajectories)} trajectories: give one per trajectory."
        )
    converted = []
    for index, trajectory in enumerate(trajectories):
        missing = [name for name in ("obs", "acts", "rews") if not hasattr(trajectory, name)]
        if missing:
            raise DemonstrationError(
                f"Trajectory {index} ({type(trajectory).__name__}) has no {missing}: sb3-icrl needs rewards, "
                "use imitation's `TrajectoryWithRew`."
            )
        infos = getattr(trajectory, "infos", None)
        if costs is not None:
            trajectory_costs = np.asarray(costs[index], dtype=np.float32)
        elif infos is not None and all(isinstance(info, dict) and cost_info_key in info for info in infos):
            trajectory_costs = np.array([info[cost_info_key] for info in infos], dtype=np.float32)
        else:
            raise DemonstrationError(
                f"Trajectory {index} has no true costs: its infos lack {cost_info_key!r}. Pass `costs=[...]` "
                "(one array per trajectory) or the right `cost_info_key`."
            )
        try:
            converted.append(
                Trajectory(
                    obs=np.asarray(trajectory.obs),
                    acts=np.asarray(trajectory.acts),
                    infos=None if infos is None else np.asarray(infos, dtype=object),
                    terminal=bool(getattr(trajectory, "terminal", False)),
                    rews=np.asarray(trajectory.rews, dtype=np.result_type(np.asarray(trajectory.rews).dtype, np.float32)),
                    costs=trajectory_costs,
                )
            )
        except ValueError as error:
            raise DemonstrationError(f"Trajectory {index} cannot be converted: {error}") from error
    return converted
