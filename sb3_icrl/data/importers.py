"""
Demonstrations recorded by other code, converted to :class:`~sb3_icrl.data.types.Demonstrations`:

- :func:`from_arrays`: flat arrays (one row per step) with episode boundaries, for anything else;
- :func:`from_malik_rollouts`: the ``rollouts/<i>.pkl`` files of Malik et al.'s ICRL code (ICML 2021);
- :func:`from_liu_pickles`: the ``scene-<id>_len-<T>_<reasons>.pkl`` files of Liu et al.'s ICRL benchmark (ICLR 2023).

What a source does not record is flagged in the metadata rather than guessed: ``true_costs_known`` (the true cost of
each step; when false the ``costs`` are zeros and say nothing about the constraint) and ``rewards_known`` (when false
the per-step ``rews`` are zeros). Save the result with :func:`~sb3_icrl.data.serialize.save` to get an ``.npz`` the
rest of the library loads.

Given the ``env_id`` of a MuJoCo env that can be built here, each importer replays the data on it
(:func:`~sb3_icrl.data.checks.import_replay_check`): data whose observations and actions are off by one step, or that
does not follow the env's dynamics (recorded on another robot with observations of the same shape), is refused;
aligned data that replays only roughly (other physics) passes with a warning. An ``env_id`` of sb3-icrl's that does not
exist (a typo) is refused; one of other code that is not registered here is stored unchecked, with a warning.
``check_replay=False`` imports the data as it is.

The pickles are read with an unpickler that only rebuilds numpy arrays and plain Python containers: a file that
holds anything else is refused instead of running its code.
"""

import os
import pathlib
import pickle
import re
from collections.abc import Sequence
from typing import Any

import numpy as np

from sb3_icrl.data.checks import import_replay_check
from sb3_icrl.data.serialize import DemonstrationError, check_imported_values
from sb3_icrl.data.types import Demonstrations, Trajectory

#: Globals an imported pickle may reference: what numpy needs to rebuild arrays and scalars, and plain containers
_SAFE_GLOBALS = {
    ("numpy", "ndarray"),
    ("numpy", "dtype"),
    ("numpy.core.multiarray", "_reconstruct"),
    ("numpy.core.multiarray", "scalar"),
    ("numpy._core.multiarray", "_reconstruct"),
    ("numpy._core.multiarray", "scalar"),
    ("numpy.core.numeric", "_frombuffer"),
    ("numpy._core.numeric", "_frombuffer"),
    ("builtins", "dict"),
    ("builtins", "list"),
    ("builtins", "tuple"),
    ("collections", "OrderedDict"),
    ("_codecs", "encode"),
}
_LIU_FILE_PATTERN = re.compile(r"^scene-(?P<scene>.+?)_len-(?P<length>\d+)(?:_(?P<reasons>.*))?\.pkl$")


def is_safe_global(module: str, name: str) -> bool:
    """Whether an imported file may name ``module.name``: what rebuilds numpy arrays and scalars, plain containers."""
    return (module, name) in _SAFE_GLOBALS or (module == "numpy" and name.startswith(("float", "int", "uint", "bool")))


class _ArrayUnpickler(pickle.Unpickler):
    """Unpickles numpy arrays and plain containers only."""

    def find_class(self, module: str, name: str) -> Any:
        if is_safe_global(module, name):
            return super().find_class(module, name)
        raise pickle.UnpicklingError(f"refusing to load {module}.{name}: only numpy arrays and plain containers are read")


def read_pickle(path: str | os.PathLike) -> dict[str, Any]:
    """
    Read a pickled dict of numpy arrays without running code from the file.

    :param path: The ``.pkl`` file
    :return: Its dict
    """
    path = pathlib.Path(path)
    if not path.is_file():
        raise DemonstrationError(f"No pickle at {path}.")
    try:
        with open(path, "rb") as file:
            content = _ArrayUnpickler(file).load()
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError) as error:
        raise DemonstrationError(f"{path} is not a pickle of numpy arrays ({error}).") from error
    if not isinstance(content, dict):
        raise DemonstrationError(f"{path} holds a {type(content).__name__}, expected a dict of arrays.")
    return content


def _checked(demonstrations: Demonstrations, env_id: str | None, check_replay: bool, importer: str) -> Demonstrations:
    """The demonstrations, once replayed on ``env_id`` (:func:`~sb3_icrl.data.checks.import_replay_check`)."""
    if check_replay:
        import_replay_check(demonstrations, env_id, importer)
    return demonstrations


def _trajectory(
    obs: np.ndarray,
    acts: np.ndarray,
    rews: np.ndarray | None,
    costs: np.ndarray | None,
    terminal: bool,
    source: str,
) -> Trajectory:
    length = len(acts)
    try:
        trajectory = Trajectory(
            obs=np.asarray(obs),
            acts=np.asarray(acts),
            infos=None,
            terminal=bool(terminal),
            rews=np.zeros(length, dtype=np.float32) if rews is None else _as_float(rews),
            costs=np.zeros(length, dtype=np.float32) if costs is None else _as_float(costs),
        )
    except ValueError as error:
        raise DemonstrationError(f"{source}: {error}") from error
    # Here, naming the file and step: save() would refuse them later, without saying where they came from
    check_imported_values(trajectory, source)
    return trajectory


def _as_float(values: Any) -> np.ndarray:
    array = np.asarray(values)
    return array if np.issubdtype(array.dtype, np.floating) else array.astype(np.float32)


def _split_points(
    n_steps: int, episode_starts: Sequence[bool] | np.ndarray | None, episode_lengths: Sequence[int] | np.ndarray | None
) -> np.ndarray:
    """Boundaries ``[0, ..., n_steps]`` of the episodes in the flat arrays."""
    if episode_starts is not None and episode_lengths is not None:
        raise DemonstrationError("Give `episode_starts` or `episode_lengths`, not both.")
    if episode_lengths is not None:
        lengths = np.asarray(episode_lengths)
        if lengths.ndim != 1 or lengths.dtype.kind not in "iu" or np.any(lengths < 1):
            raise DemonstrationError(f"`episode_lengths` must be positive integers, got {lengths.tolist()[:10]}.")
        if int(lengths.sum()) != n_steps:
            raise DemonstrationError(
                f"`episode_lengths` sum to {int(lengths.sum())}, but the arrays have {n_steps} rows (one per step)."
            )
        return np.concatenate([[0], np.cumsum(lengths)])
    if episode_starts is None:
        return np.array([0, n_steps])
    starts = np.asarray(episode_starts)
    if starts.shape != (n_steps,) or starts.dtype.kind not in "bi":
        raise DemonstrationError(f"`episode_starts` must be {n_steps} bools (one per step), got shape {starts.shape}.")
    starts = starts.astype(bool)
    if not starts[0]:
        raise DemonstrationError(
            "`episode_starts[0]` is False, but the first step always starts an episode (SB3's convention: true on the "
            "first step of each episode): set it to True, or drop the steps before the first start if the arrays begin "
            "in the middle of an episode."
        )
    return np.concatenate([np.flatnonzero(starts), [n_steps]])


def _check_next_observations(observations: np.ndarray, next_observations: Any, bounds: np.ndarray) -> None:
    """
    Refuse ``next_observations`` that are not the observations that follow inside each episode (the data is
    misaligned, or the episode boundaries are wrong).

    :param observations: ``(N,) + obs_shape``
    :param next_observations: ``(N,) + obs_shape``, the observation after each action
    :param bounds: The episode boundaries ``[0, ..., N]``
    """
    following = np.asarray(next_observations)
    if len(observations) < 2 or observations.dtype.kind not in "biuf" or following.dtype.kind not in "biuf":
        return  # no step follows another; or not numbers, refused with the field's name later
    inside = np.ones(len(observations) - 1, dtype=bool)  # step i -> i + 1 inside an episode
    inside[bounds[1:-1] - 1] = False
    pairs = len(inside)
    same = np.isclose(
        following[:-1].reshape(pairs, -1), observations[1:].reshape(pairs, -1), rtol=1e-5, atol=1e-6, equal_nan=True
    ).all(axis=1)
    differ = inside & ~same
    if differ.any():
        first, count = int(np.argmax(differ)), int(differ.sum())
        episode = int(np.searchsorted(bounds, first, side="right")) - 1
        raise DemonstrationError(
            f"`next_observations[{first}]` differs from `observations[{first + 1}]` inside episode {episode} "
            f"({count} such step{'s' if count > 1 else ''} in all): the observation after a step is the one the next step "
            "starts from. Mark where each episode starts (`episode_starts` or `episode_lengths`), or check that the "
            "arrays are aligned (a row of one shifted against the other)."
        )


def from_arrays(
    observations: np.ndarray,
    actions: np.ndarray,
    rewards: np.ndarray | None = None,
    costs: np.ndarray | None = None,
    *,
    next_observations: np.ndarray | None = None,
    episode_starts: Sequence[bool] | np.ndarray | None = None,
    episode_lengths: Sequence[int] | np.ndarray | None = None,
    terminals: Sequence[bool] | np.ndarray | None = None,
    env_id: str | None = None,
    metadata: dict[str, Any] | None = None,
    check_replay: bool = True,
) -> Demonstrations:
    """
    Build demonstrations from flat arrays, one row per step: ``observations[i]`` is the state *before*
    ``actions[i]`` (check with :func:`~sb3_icrl.data.checks.dynamics_replay_check` when unsure).

    Each episode needs the observation after its last action: from ``next_observations`` when given, otherwise the
    last step of each episode is dropped (its next observation is unknown).

    :param observations: ``(N,) + obs_shape``
    :param actions: ``(N,) + action_shape``
    :param rewards: ``(N,)``; ``None``: unknown (zeros, ``rewards_known`` false in the metadata)
    :param costs: True costs ``(N,)`` or ``(N, n_costs)``; ``None``: unknown (zeros, ``true_costs_known`` false)
    :param next_observations: Optional ``(N,) + obs_shape``, the observation after each action: inside an episode,
        the next row of ``observations``
    :param episode_starts: ``N`` bools, true on the first step of each episode (SB3's convention; so ``True`` first)
    :param episode_lengths: Or the length of each episode, in order; neither: a single episode
    :param terminals: One bool per episode: whether it ended in a terminal state (default: none did)
    :param env_id: The env the data was recorded on (stored as ``env_id`` in the metadata)
    :param metadata: More metadata to store
    :param check_replay: Replay the data on ``env_id`` (:func:`~sb3_icrl.data.checks.import_replay_check`, where
        it can be built); ``False``: import the data as it is
    :return: The demonstrations
    """
    observations, actions = np.asarray(observations), np.asarray(actions)
    named = {
        "observations": observations,
        "actions": actions,
        "rewards": rewards,
        "costs": costs,
        "next_observations": next_observations,
    }
    for name, values in named.items():
        if values is not None and np.ndim(values) == 0:
            raise DemonstrationError(
                f"`{name}` must be an array with one row per step, got the single value {np.asarray(values).item()!r}."
            )
    n_steps = len(actions)
    if n_steps == 0:
        raise DemonstrationError("`actions` is empty: give at least one step.")
    for name, values in named.items():
        if values is not None and len(values) != n_steps:
            raise DemonstrationError(f"`{name}` has {len(values)} rows, `actions` {n_steps}: give one row per step.")
    if next_observations is not None and np.shape(next_observations)[1:] != observations.shape[1:]:
        raise DemonstrationError(
            f"`next_observations` have shape {np.shape(next_observations)[1:]} per step, `observations` "
            f"{observations.shape[1:]}: give the observation after each action, of the same shape."
        )
    bounds = _split_points(n_steps, episode_starts, episode_lengths)
    if next_observations is not None:
        _check_next_observations(observations, next_observations, bounds)
    n_episodes = len(bounds) - 1
    terminal_flags = np.zeros(n_episodes, dtype=bool) if terminals is None else np.asarray(terminals, dtype=bool)
    if terminal_flags.shape != (n_episodes,):
        raise DemonstrationError(f"`terminals` must hold one bool per episode ({n_episodes}), got {terminal_flags.shape}.")
    trajectories = []
    for index in range(n_episodes):
        start, end = int(bounds[index]), int(bounds[index + 1])
        if next_observations is not None:
            obs = np.concatenate([observations[start:end], np.asarray(next_observations)[end - 1 : end]])
            last = end
        else:
            if end - start < 2:
                raise DemonstrationError(
                    f"Episode {index} has {end - start} step: without `next_observations` the last step of each episode "
                    "is dropped, so every episode needs at least two."
                )
            obs, last = observations[start:end], end - 1
        trajectories.append(
            _trajectory(
                obs,
                actions[start:last],
                None if rewards is None else np.asarray(rewards)[start:last],
                None if costs is None else np.asarray(costs)[start:last],
                bool(terminal_flags[index]),
                f"episode {index}",
            )
        )
    recorded = {"source": {"format": "arrays"}, **(metadata or {})}
    recorded.setdefault("rewards_known", rewards is not None)
    recorded.setdefault("true_costs_known", costs is not None)
    if env_id is not None:
        recorded["env_id"] = env_id
    return _checked(Demonstrations(trajectories, recorded), env_id, check_replay, "from_arrays")


def _pickle_paths(paths: str | os.PathLike | Sequence[str | os.PathLike], pattern: str) -> list[pathlib.Path]:
    """The files given, or those matching ``pattern`` in a folder given, in natural order (``2.pkl`` before ``10.pkl``)."""
    if isinstance(paths, (str, os.PathLike)):
        path = pathlib.Path(paths)
        if path.is_dir():
            found = sorted(
                path.glob(pattern), key=lambda p: [int(s) if s.isdigit() else s for s in re.split(r"(\d+)", p.name)]
            )
            if not found:
                raise DemonstrationError(f"No {pattern} files in {path}.")
            return found
        return [path]
    if len(paths) == 0:
        raise DemonstrationError("No files given.")
    return [pathlib.Path(p) for p in paths]


def _require_keys(data: dict[str, Any], keys: Sequence[str], path: pathlib.Path, hint: str) -> None:
    missing = [key for key in keys if key not in data]
    if missing:
        raise DemonstrationError(f"{path} lacks {missing} (has {sorted(data)}): {hint}")


def from_malik_rollouts(
    paths: str | os.PathLike | Sequence[str | os.PathLike],
    env_id: str | None = None,
    check_replay: bool = True,
) -> Demonstrations:
    """
    Import the expert rollouts of Malik et al.'s ICRL code (``expert_data/<Env>/files/EXPERT/rollouts/<i>.pkl``).

    Each file holds one episode, recorded through a ``VecEnv``: ``observations`` ``(T, obs_dim)`` (unnormalised),
    ``actions`` ``(T, act_dim)`` (as the policy output them, not clipped), ``rewards`` and ``lengths`` of shape
    ``(1,)`` (the episode's return and length). Row ``t`` of ``observations`` is the state *after* action ``t``, and
    the last row is the reset state of the next episode (the ``VecEnv`` resets on ``done``). The episode's first state
    and its final state are thus not recorded: the trajectory built here starts at the state after the first action,
    ``obs = observations[:-1]`` (``T - 1`` states) and ``acts = actions[1:-1]`` (``T - 2`` actions, the first and last
    dropped). Files of their "airl" scheme (``current_states``, ``next_states``) give ``obs = current_states``,
    ``acts = actions[:-1]``.

    Per-step rewards and the true costs are not recorded: both are zeros, flagged by ``rewards_known`` and
    ``true_costs_known`` (false) in the metadata; the recorded returns are in ``metadata["episode_returns_recorded"]``.
    Whether an episode ended in a terminal state is not recorded either (``terminal`` is false).

    :param paths: A ``rollouts`` folder (all its ``*.pkl``), or a list of files
    :param env_id: The env the data was recorded on, for the metadata
    :param check_replay: Replay the data on ``env_id`` (:func:`~sb3_icrl.data.checks.import_replay_check`, where
        it can be built); ``False``: import the data as it is
    :return: The demonstrations, one trajectory per file
    """
    trajectories, returns, files = [], [], []
    for path in _pickle_paths(paths, "*.pkl"):
        data = read_pickle(path)
        actions = np.asarray(data.get("actions"))
        if "current_states" in data:
            _require_keys(data, ("current_states", "actions"), path, "not a rollout of the 'airl' scheme.")
            obs, acts = np.asarray(data["current_states"]), actions[:-1]
        else:
            _require_keys(
                data, ("observations", "actions"), path, "Malik et al.'s rollouts hold `observations` and `actions`."
            )
            observations = np.asarray(data["observations"])
            if len(observations) != len(actions):
                raise DemonstrationError(
                    f"{path}: {len(observations)} observations for {len(actions)} actions; a rollout has one of each per step."
                )
            if len(actions) < 3:
                raise DemonstrationError(
                    f"{path}: {len(actions)} steps; at least 3 are needed (the first and last are dropped)."
                )
            obs, acts = observations[:-1], actions[1:-1]
        trajectories.append(_trajectory(obs, acts, None, None, False, str(path)))
        returns.append(float(np.sum(data["rewards"])) if "rewards" in data else None)
        if returns[-1] is not None and not np.isfinite(returns[-1]):
            raise DemonstrationError(f"{path}: its recorded return is NaN or infinite: the rollout is broken; leave it out.")
        files.append(path.name)
    metadata: dict[str, Any] = {
        "source": {"format": "malik-rollouts", "files": files},
        "rewards_known": False,
        "true_costs_known": False,
        "episode_returns_recorded": returns,
    }
    if env_id is not None:
        metadata["env_id"] = env_id
    return _checked(Demonstrations(trajectories, metadata), env_id, check_replay, "from_malik_rollouts")


def from_liu_pickles(
    paths: str | os.PathLike | Sequence[str | os.PathLike],
    env_id: str | None = None,
    observation_key: str = "original_observations",
    check_replay: bool = True,
) -> Demonstrations:
    """
    Import the expert data of Liu et al.'s ICRL benchmark (``scene-<id>_len-<T>_<reasons>.pkl``).

    Each file holds one episode: ``original_observations`` ``(T, obs_dim)`` (unnormalised; ``observations`` holds the
    same states normalised by the expert's ``VecNormalize``), ``actions`` ``(T, act_dim)``, ``reward`` ``(T,)`` (as the
    expert's ``VecEnv`` returned them) and ``reward_sum``. Row ``t`` is the state *before* action ``t``; the state
    after the last action is not recorded, so the trajectory built here has ``obs`` = the ``T`` states and
    ``acts = actions[:-1]``, ``rews = reward[:-1]``. The file name's scene id, length and termination reasons go into
    ``metadata["episodes"]``; ``terminal`` is true when a reason other than a time-out ended the episode
    (``collision``, ``off_road``, ``constraint``, ...). The true costs are not recorded (zeros, ``true_costs_known``
    false in the metadata).

    :param paths: A folder (all its ``scene-*_len-*.pkl``), or a list of files
    :param env_id: The env the data was recorded on, for the metadata
    :param observation_key: ``"original_observations"`` (raw states) or ``"observations"`` (the expert's normalised ones)
    :param check_replay: Replay the data on ``env_id`` (:func:`~sb3_icrl.data.checks.import_replay_check`, where
        it can be built); ``False``: import the data as it is
    :return: The demonstrations, one trajectory per file
    """
    trajectories, episodes, rewards_recorded = [], [], []
    for path in _pickle_paths(paths, "scene-*_len-*.pkl"):
        data = read_pickle(path)
        _require_keys(
            data,
            (observation_key, "actions"),
            path,
            f"Liu et al.'s files hold `{observation_key}` and `actions`; older MuJoCo files without "
            "`original_observations` follow Malik et al.'s layout: use `from_malik_rollouts`.",
        )
        obs, actions = np.asarray(data[observation_key]), np.asarray(data["actions"])
        if len(obs) != len(actions) or len(actions) < 2:
            raise DemonstrationError(
                f"{path}: {len(obs)} observations for {len(actions)} actions; expected one of each per step, at least two."
            )
        rewards = np.asarray(data["reward"]).ravel() if "reward" in data else None
        if rewards is not None and len(rewards) != len(actions):
            raise DemonstrationError(f"{path}: {len(rewards)} rewards for {len(actions)} actions; expected one per step.")
        rewards_recorded.append(rewards is not None)
        match = _LIU_FILE_PATTERN.match(path.name)
        reasons = [reason for reason in (match["reasons"] or "").split("-") if reason] if match else []
        if match and int(match["length"]) != len(actions):
            raise DemonstrationError(f"{path}: the name says {match['length']} steps, the file holds {len(actions)}.")
        terminal = any(reason not in ("time_out", "Game Finished") for reason in reasons)
        trajectories.append(
            _trajectory(obs, actions[:-1], None if rewards is None else rewards[:-1], None, terminal, str(path))
        )
        episodes.append(
            {
                "file": path.name,
                "scene": match["scene"] if match else None,
                "termination_reasons": reasons,
                "reward_sum": float(np.sum(data["reward_sum"])) if "reward_sum" in data else None,
            }
        )
    metadata: dict[str, Any] = {
        "source": {"format": "liu-pickles", "observation_key": observation_key},
        "episodes": episodes,
        "rewards_known": all(rewards_recorded),
        "true_costs_known": False,
    }
    if env_id is not None:
        metadata["env_id"] = env_id
    return _checked(Demonstrations(trajectories, metadata), env_id, check_replay, "from_liu_pickles")
