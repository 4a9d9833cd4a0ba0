"""
Expert demonstrations: trajectories with the true cost of every step, and a flat transitions view.

The field names and shapes follow the ``imitation`` library (``imitation.data.types.TrajectoryWithRew``:
``obs`` with ``T + 1`` rows, ``acts``, ``infos``, ``terminal``, ``rews``), with ``costs`` added, so that
code written for ``imitation`` reads our trajectories field by field.
"""

import dataclasses
from collections.abc import Iterator, Sequence
from typing import Any, overload

import numpy as np


@dataclasses.dataclass(frozen=True, eq=False)
class Trajectory:
    """
    One episode of a policy, with rewards and true costs.

    :param obs: Observations, shape ``(T + 1,) + obs_shape`` (the observation after the last action included)
    :param acts: Actions, shape ``(T,) + action_shape``
    :param infos: Optional array of ``T`` info dicts (not needed by ICRL; not read back from files by default)
    :param terminal: Whether the episode ended in a terminal state (``terminated``), not a time limit
    :param rews: Rewards, float, shape ``(T,)``
    :param costs: True costs, float, shape ``(T,)`` or ``(T, n_costs)``; a step breaks the constraint when its cost is > 0
    """

    obs: np.ndarray
    acts: np.ndarray
    infos: np.ndarray | None
    terminal: bool
    rews: np.ndarray
    costs: np.ndarray

    def __post_init__(self) -> None:
        length = len(self.acts)
        if length == 0:
            raise ValueError("Degenerate trajectory: it must have at least one action.")
        if len(self.obs) != length + 1:
            raise ValueError(f"A trajectory has one more observation than actions: got {len(self.obs)} obs for {length} acts.")
        if self.infos is not None and len(self.infos) != length:
            raise ValueError(f"`infos`, when given, has one entry per action: got {len(self.infos)} for {length} acts.")
        for name in ("rews", "costs"):
            value = getattr(self, name)
            if not isinstance(value, np.ndarray) or not np.issubdtype(value.dtype, np.floating):
                raise ValueError(
                    f"`{name}` must be a float numpy array, got {type(value).__name__} {getattr(value, 'dtype', '')}."
                )
        if self.rews.shape != (length,):
            raise ValueError(f"`rews` must have shape ({length},) (one per action), got {self.rews.shape}.")
        if self.costs.ndim not in (1, 2) or len(self.costs) != length:
            raise ValueError(f"`costs` must have shape ({length},) or ({length}, n_costs), got {self.costs.shape}.")

    def __len__(self) -> int:
        """Number of transitions (actions)."""
        return len(self.acts)

    @property
    def step_violations(self) -> np.ndarray:
        """Boolean ``(T,)``: whether each step breaks a true constraint (any cost > 0)."""
        return np.any(self.costs.reshape(len(self), -1) > 0, axis=1)

    @property
    def violates(self) -> bool:
        """Whether any step of the trajectory breaks a true constraint."""
        return bool(self.step_violations.any())

    @property
    def episode_return(self) -> float:
        """Sum of the rewards."""
        return float(np.sum(self.rews))

    @property
    def episode_cost(self) -> float:
        """Sum of the true costs (over all constraints)."""
        return float(np.sum(self.costs))

    @property
    def feasible_return(self) -> float:
        """Reward summed until (excluding) the first step that breaks the constraint (the paper's feasible reward)."""
        violations = self.step_violations
        end = int(np.argmax(violations)) if violations.any() else len(self)
        return float(np.sum(self.rews[:end]))


@dataclasses.dataclass(frozen=True, eq=False)
class Transitions:
    """
    Flat view of trajectories, one row per step, for constraint learning (field names of ``imitation``'s
    ``TransitionsWithRew``, plus ``costs``).

    ``dones[i]`` is true on the last step of a trajectory that ended in a terminal state (as ``imitation``'s
    ``flatten_trajectories``); ``episode_ends[i]`` marks the last step of every trajectory (time limit or not).

    Indexing with an integer gives a dict of the row's fields; a slice or an index array gives ``Transitions``.

    :param obs: Observation before each action, shape ``(N,) + obs_shape``
    :param acts: Actions, shape ``(N,) + action_shape``
    :param next_obs: Observation after each action
    :param dones: Boolean ``(N,)``, true where ``next_obs`` is a terminal state
    :param rews: Rewards, ``(N,)``
    :param costs: True costs, ``(N,)`` or ``(N, n_costs)`` (for evaluation: learners must not see them)
    :param episode_ends: Boolean ``(N,)``, true on the last step of each trajectory
    """

    obs: np.ndarray
    acts: np.ndarray
    next_obs: np.ndarray
    dones: np.ndarray
    rews: np.ndarray
    costs: np.ndarray
    episode_ends: np.ndarray

    def __post_init__(self) -> None:
        length = len(self.obs)
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if len(value) != length:
                raise ValueError(f"Every field has one row per transition: `{field.name}` has {len(value)}, `obs` {length}.")
        if self.next_obs.shape != self.obs.shape:
            raise ValueError(f"`obs` and `next_obs` must have the same shape: {self.obs.shape} != {self.next_obs.shape}.")

    def __len__(self) -> int:
        return len(self.obs)

    @overload
    def __getitem__(self, key: int) -> dict[str, np.ndarray]: ...

    @overload
    def __getitem__(self, key: slice | np.ndarray) -> "Transitions": ...

    def __getitem__(self, key: Any) -> "dict[str, np.ndarray] | Transitions":
        items = {field.name: getattr(self, field.name)[key] for field in dataclasses.fields(self)}
        if isinstance(key, (int, np.integer)):
            return items
        return Transitions(**items)


def flatten_trajectories(trajectories: Sequence[Trajectory]) -> Transitions:
    """
    Concatenate trajectories into one :class:`Transitions` (``imitation.data.rollout.flatten_trajectories``, with costs).

    :param trajectories: At least one trajectory
    :return: The transitions, in trajectory order
    """
    if len(trajectories) == 0:
        raise ValueError("Cannot flatten an empty list of trajectories.")
    dones, ends = [], []
    for trajectory in trajectories:
        end = np.zeros(len(trajectory), dtype=bool)
        end[-1] = True
        ends.append(end)
        dones.append(end & trajectory.terminal)
    return Transitions(
        obs=np.concatenate([t.obs[:-1] for t in trajectories]),
        acts=np.concatenate([t.acts for t in trajectories]),
        next_obs=np.concatenate([t.obs[1:] for t in trajectories]),
        dones=np.concatenate(dones),
        rews=np.concatenate([t.rews for t in trajectories]),
        costs=np.concatenate([t.costs for t in trajectories]),
        episode_ends=np.concatenate(ends),
    )


class Demonstrations(Sequence[Trajectory]):
    """
    A list of trajectories with the metadata of the file they came from (a ``Sequence`` of :class:`Trajectory`).

    :param trajectories: The trajectories
    :param metadata: The JSON sidecar's content (env id, expert, statistics, checksum, versions); empty if none
    """

    def __init__(self, trajectories: Sequence[Trajectory], metadata: dict[str, Any] | None = None):
        self.trajectories = list(trajectories)
        self.metadata = {} if metadata is None else metadata
        self._transitions: Transitions | None = None

    def __len__(self) -> int:
        return len(self.trajectories)

    @overload
    def __getitem__(self, index: int) -> Trajectory: ...

    @overload
    def __getitem__(self, index: slice) -> list[Trajectory]: ...

    def __getitem__(self, index: int | slice) -> Trajectory | list[Trajectory]:
        return self.trajectories[index]

    def __iter__(self) -> Iterator[Trajectory]:
        return iter(self.trajectories)

    def __repr__(self) -> str:
        env_id = self.metadata.get("env_id", "?")
        return f"Demonstrations(env_id={env_id!r}, n_trajectories={len(self)}, n_transitions={self.n_transitions})"

    @property
    def n_transitions(self) -> int:
        return sum(len(t) for t in self.trajectories)

    @property
    def transitions(self) -> Transitions:
        """The flat view (computed once)."""
        if self._transitions is None:
            self._transitions = flatten_trajectories(self.trajectories)
        return self._transitions

    @property
    def episode_returns(self) -> np.ndarray:
        return np.array([t.episode_return for t in self.trajectories])

    @property
    def violations(self) -> np.ndarray:
        """Boolean, one per trajectory: whether it breaks the true constraint."""
        return np.array([t.violates for t in self.trajectories], dtype=bool)
