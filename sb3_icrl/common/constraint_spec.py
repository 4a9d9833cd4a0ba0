"""
How an environment declares its true constraint, and the one function that reads the declaration.

The true constraint is for evaluation, plots and identification metrics only: learners never see it. An env declares
it with a ``constraint_spec`` attribute, the same way for the benchmark envs and for yours::

    import gymnasium
    from sb3_icrl import ConstraintSpec, FeatureConstraint

    class MyEnv(gymnasium.Env):
        # Fixed constraint: a class attribute, read without making the env
        constraint_spec = ConstraintSpec(features=(FeatureConstraint(obs_index=0, threshold=0.6, op=">", name="x"),))

    class MyTunableEnv(gymnasium.Env):
        def __init__(self, limit: float = 0.6):
            ...
            # Constraint set by the constructor's arguments: an instance attribute (or a property)
            self.constraint_spec = ConstraintSpec(features=(FeatureConstraint(0, limit, ">", "x"),))

:func:`get_constraint_spec` accepts an env, a vectorised env or a registered id (then the env is made once with the
given keyword arguments, unless its class attribute already is the declaration). For an env class you cannot edit,
:func:`declare_constraint` declares it for a registered id.
"""

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

from sb3_icrl.common.env_ids import resolve_env_id

#: Comparisons of :class:`FeatureConstraint`: the constraint is broken when ``obs[obs_index] <op> threshold``
OPERATORS: dict[str, Callable[[np.ndarray, float], np.ndarray]] = {
    "<=": np.less_equal,
    "<": np.less,
    ">=": np.greater_equal,
    ">": np.greater,
}
#: Attribute of an env (class or instance) that holds its declaration
SPEC_ATTRIBUTE = "constraint_spec"


@dataclass(frozen=True)
class FeatureConstraint:
    """
    A true constraint that is a threshold on one observation feature: broken when ``obs[obs_index] <op> threshold``.

    :param obs_index: Index of the constrained feature in the (flat) observation
    :param threshold: The threshold
    :param op: ``"<="``, ``"<"``, ``">="`` or ``">"``: the side of the threshold where the constraint is broken
    :param name: Name of the constrained quantity (axis labels; ``obs[<index>]`` when empty)
    """

    obs_index: int
    threshold: float
    op: str
    name: str = ""

    def __post_init__(self) -> None:
        if isinstance(self.obs_index, bool) or not isinstance(self.obs_index, (int, np.integer)) or self.obs_index < 0:
            raise ValueError(f"FeatureConstraint: `obs_index` must be an int >= 0, got {self.obs_index!r}.")
        if self.op not in OPERATORS:
            raise ValueError(f"FeatureConstraint: `op` must be one of {', '.join(OPERATORS)}, got {self.op!r}.")
        try:
            threshold = float(self.threshold)
        except (TypeError, ValueError):
            threshold = math.nan
        if not math.isfinite(threshold):
            raise ValueError(f"FeatureConstraint: `threshold` must be a finite number, got {self.threshold!r}.")
        object.__setattr__(self, "obs_index", int(self.obs_index))
        object.__setattr__(self, "threshold", threshold)
        object.__setattr__(self, "name", str(self.name or f"obs[{int(self.obs_index)}]"))

    @property
    def unsafe_side(self) -> str:
        """``"below"`` when values under the threshold break the constraint, else ``"above"``."""
        return "below" if self.op in ("<=", "<") else "above"

    def margin(self, values: Any) -> np.ndarray:
        """
        :param values: Values of the constrained feature
        :return: Their distance to the threshold on the allowed side, negative beyond it (on the threshold itself: 0)
        """
        values = np.asarray(values, dtype=np.float64)
        return values - self.threshold if self.unsafe_side == "below" else self.threshold - values

    def violated(self, observations: Any) -> np.ndarray:
        """
        :param observations: One observation ``(obs_dim,)`` or a batch ``(n, obs_dim)``
        :return: Whether each breaks the constraint, ``(n,)`` booleans (``()`` for one observation)
        """
        obs = np.asarray(observations, dtype=np.float64)
        if obs.ndim == 0 or obs.shape[-1] <= self.obs_index:
            raise ValueError(
                f"FeatureConstraint {self.name!r} reads obs[{self.obs_index}], but the observations have shape {obs.shape}."
            )
        return OPERATORS[self.op](obs[..., self.obs_index], self.threshold)


@dataclass(frozen=True)
class ConstraintSpec:
    """
    The true constraint of an env: thresholds on observation features, a set of unsafe discrete states, and/or a
    cost function. The true cost of a state is 1 when any part of the declaration is broken in it.

    :param features: Feature thresholds (several: the constraint is broken when any one is)
    :param unsafe_states: Discrete observations (e.g. grid cells) that break the constraint
    :param cost_fn: ``cost_fn(observations, actions) -> costs``, batched, for constraints that are neither; when given,
        it is the true cost (the features then only say what to plot)
    """

    features: tuple[FeatureConstraint, ...] = ()
    unsafe_states: frozenset[int] | None = None
    cost_fn: Callable[[np.ndarray, np.ndarray | None], Any] | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        features = (self.features,) if isinstance(self.features, FeatureConstraint) else tuple(self.features)
        for feature in features:
            if not isinstance(feature, FeatureConstraint):
                raise TypeError(f"ConstraintSpec: `features` must hold FeatureConstraint objects, got {feature!r}.")
        object.__setattr__(self, "features", features)
        if self.unsafe_states is not None:
            object.__setattr__(self, "unsafe_states", frozenset(int(state) for state in self.unsafe_states))
        if self.cost_fn is not None and not callable(self.cost_fn):
            raise TypeError(f"ConstraintSpec: `cost_fn` must be callable, got {self.cost_fn!r}.")
        if not features and self.unsafe_states is None and self.cost_fn is None:
            raise ValueError("A ConstraintSpec needs `features`, `unsafe_states` or `cost_fn`: it declares nothing.")

    def true_cost(self, observations: Any, actions: Any = None) -> np.ndarray:
        """
        The true cost of a batch of observations (the state reached by a step, as ``info["cost"]`` of the benchmark
        envs), for evaluation only.

        :param observations: ``(n, obs_dim)``, or one observation ``(obs_dim,)`` (discrete observations: ``(n,)`` state
            indices)
        :param actions: ``(n, ...)`` actions, passed to ``cost_fn``
        :return: ``(n,)`` costs in ``{0.0, 1.0}`` (or ``cost_fn``'s values)
        """
        if self.cost_fn is not None:
            return np.asarray(self.cost_fn(np.asarray(observations), None if actions is None else np.asarray(actions)), float)
        obs = np.asarray(observations)
        if self.unsafe_states is not None and not self.features:
            states = np.atleast_1d(obs) if obs.ndim <= 1 else obs.reshape(len(obs), -1)[:, 0]
            return np.isin(states.astype(np.int64), np.fromiter(self.unsafe_states, dtype=np.int64)).astype(np.float64)
        batch = np.atleast_2d(obs)  # one observation (obs_dim,) is a batch of one
        broken = np.zeros(len(batch), dtype=bool)
        if self.unsafe_states is not None:
            broken |= np.isin(batch[:, 0].astype(np.int64), np.fromiter(self.unsafe_states, dtype=np.int64))
        for feature in self.features:
            broken |= feature.violated(batch)
        return broken.astype(np.float64)


#: Declarations for registered ids whose env class does not declare one (see :func:`declare_constraint`)
_DECLARED: dict[str, "ConstraintSpec | FeatureConstraint | Callable[..., ConstraintSpec]"] = {}
#: Declarations read by making an env, by (id, keyword arguments)
_CACHE: dict[tuple[str, str], "ConstraintSpec | None"] = {}


def as_constraint_spec(declaration: Any, source: str = "constraint_spec") -> ConstraintSpec | None:
    """
    A declaration as a :class:`ConstraintSpec`: a spec, one :class:`FeatureConstraint` or several, or ``None``.

    :param declaration: What the env declares
    :param source: Where it comes from (for the error message)
    :raises TypeError: For anything else
    """
    if declaration is None or isinstance(declaration, ConstraintSpec):
        return declaration
    if isinstance(declaration, FeatureConstraint):
        return ConstraintSpec(features=(declaration,))
    if isinstance(declaration, (list, tuple)) and declaration and all(isinstance(f, FeatureConstraint) for f in declaration):
        return ConstraintSpec(features=tuple(declaration))
    raise TypeError(
        f"{source} must be a ConstraintSpec or FeatureConstraint(s) from sb3_icrl.common.constraint_spec, got {declaration!r}."
    )


def declare_constraint(env_id: str, spec: "ConstraintSpec | FeatureConstraint | Callable[..., ConstraintSpec]") -> None:
    """
    Declare the true constraint of a registered id whose env class you cannot edit (call it where you register it).

    :param env_id: The registered id
    :param spec: The declaration, or a function of the env's keyword arguments that returns it
    """
    if not isinstance(spec, (ConstraintSpec, FeatureConstraint)) and not callable(spec):
        raise TypeError(
            f"declare_constraint({env_id!r}): expected a ConstraintSpec, a FeatureConstraint or a function, got {spec!r}."
        )
    _DECLARED[env_id] = spec
    for key in [key for key in _CACHE if key[0] == env_id]:
        del _CACHE[key]


def _from_env(env: Any) -> ConstraintSpec | None:
    from stable_baselines3.common.vec_env import VecEnv

    if isinstance(env, VecEnv):
        try:
            declaration = env.get_attr(SPEC_ATTRIBUTE, [0])[0]
        except AttributeError:
            declaration = None
        env_id = getattr(env.get_attr("spec", [0])[0], "id", None)
    else:
        declaration = getattr(getattr(env, "unwrapped", env), SPEC_ATTRIBUTE, None)
        env_id = getattr(getattr(env, "spec", None), "id", None)
    if declaration is None and env_id in _DECLARED:
        kwargs = dict(getattr(getattr(env, "spec", None), "kwargs", None) or {})
        return _declared(env_id, kwargs)
    return as_constraint_spec(declaration, f"{type(getattr(env, 'unwrapped', env)).__name__}.{SPEC_ATTRIBUTE}")


def _declared(env_id: str, env_kwargs: Mapping[str, Any]) -> ConstraintSpec | None:
    declaration = _DECLARED[env_id]
    if callable(declaration) and not isinstance(declaration, (ConstraintSpec, FeatureConstraint)):
        declaration = declaration(**env_kwargs)
    return as_constraint_spec(declaration, f"declare_constraint({env_id!r})")


def get_constraint_spec(env_or_id: Any, env_kwargs: Mapping[str, Any] | None = None) -> ConstraintSpec | None:
    """
    The true constraint an env declares (see the module's docstring), or ``None`` when it declares none.

    :param env_or_id: A gymnasium env (wrapped or not), an SB3 ``VecEnv`` or a registered id
    :param env_kwargs: With an id: the keyword arguments the env is made with (thresholds may depend on them)
    :return: The declaration
    :raises ValueError: For an id that is not registered
    """
    if not isinstance(env_or_id, str):
        return _from_env(env_or_id)
    env_id = env_or_id
    if ":" in env_id:  # gymnasium's MODULE:EnvId
        env_id = resolve_env_id(env_id)
    if env_id not in gym.registry and f"sb3_icrl/{env_id}" in gym.registry:
        env_id = f"sb3_icrl/{env_id}"
    if env_id not in gym.registry:
        raise ValueError(f"Unknown env {env_or_id!r}: register it (or import the module that does) first.")
    registered = gym.spec(env_id)
    kwargs = {**(registered.kwargs or {}), **dict(env_kwargs or {})}
    if env_id in _DECLARED:
        return _declared(env_id, kwargs)
    entry_point: Any = registered.entry_point
    if isinstance(entry_point, str):
        from gymnasium.envs.registration import load_env_creator

        entry_point = load_env_creator(entry_point)
    static = getattr(entry_point, SPEC_ATTRIBUTE, None)
    if isinstance(static, (ConstraintSpec, FeatureConstraint, tuple, list)):
        return as_constraint_spec(static, f"{getattr(entry_point, '__name__', entry_point)}.{SPEC_ATTRIBUTE}")
    key = (env_id, repr(sorted(kwargs.items())))
    if key not in _CACHE:
        # The declaration depends on the instance (a property, or set in __init__): make the env once
        env = gym.make(env_id, disable_env_checker=True, **dict(env_kwargs or {}))
        try:
            _CACHE[key] = _from_env(env)
        finally:
            env.close()
    return _CACHE[key]
