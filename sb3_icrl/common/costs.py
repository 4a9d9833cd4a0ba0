"""Reading per-step costs from a VecEnv's infos or from a batched cost function, with clear errors."""

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

#: ``cost_fn(observations, actions) -> costs``: observations ``(n_envs, *obs_shape)`` as the env returned them
#: (before any ``VecNormalize``), actions ``(n_envs, *action_shape)`` as sent to the env; costs ``(n_envs,)``
#: or ``(n_envs, n_costs)``.
CostFn = Callable[[np.ndarray, np.ndarray], np.ndarray]


#: The smallest float that float32 rounds to infinity (half an ulp above its largest finite value)
FLOAT32_OVERFLOW = 2.0**128 - 2.0**103


class CostError(ValueError):
    """A per-step cost is missing or malformed."""


def as_cost_array(costs: Any, n_envs: int, n_costs: int, source: str, signed: bool = False) -> np.ndarray:
    """
    Validate and reshape a batch of costs to ``(n_envs, n_costs)`` float32.

    :param costs: Costs for every env, shape ``(n_envs,)`` or ``(n_envs, n_costs)``
    :param n_envs: Number of environments
    :param n_costs: Number of constraints
    :param source: Where the costs come from, used in the error message
    :param signed: Accept costs below 0 (a learned cost charged as a penalty on the reward, IRL-Plus's); otherwise a
        cost counts violations and must be >= 0
    :return: The costs as a float32 array of shape ``(n_envs, n_costs)``
    """
    try:
        # dtype checked first: np.asarray(["0.5"], dtype=np.float32) would silently parse text
        raw = np.asarray(costs)
        if raw.dtype.kind not in "biuf":
            raise TypeError(f"dtype {raw.dtype}")
        array = np.asarray(raw, dtype=np.float32)
    except (TypeError, ValueError) as error:
        raise CostError(f"{source} returned costs that are not numbers: {costs!r}.") from error
    if array.shape == (n_envs,) and n_costs == 1:
        array = array.reshape(n_envs, 1)
    if array.shape != (n_envs, n_costs):
        raise CostError(
            f"{source} returned costs of shape {array.shape}, expected ({n_envs},) or ({n_envs}, {n_costs}) "
            f"for {n_envs} env(s) and {n_costs} constraint(s). Check the model's `cost_budget` "
            "(one budget per constraint) against the number of costs the environment reports."
        )
    if not np.all(np.isfinite(array)):
        raise CostError(f"{source} returned non-finite costs: {array.tolist()}.")
    if not signed and np.any(array < 0):
        raise CostError(f"{source} returned negative costs: {array.tolist()}. A cost counts violations and must be >= 0.")
    return array


def costs_from_infos(infos: Sequence[dict[str, Any]], key: str, n_costs: int, env_names: Sequence[str]) -> np.ndarray:
    """
    Collect the per-step costs that each env reports in ``info[key]``.

    :param infos: One info dict per env, as returned by ``VecEnv.step``
    :param key: The info key holding the cost (a float, or a vector with one entry per constraint)
    :param n_costs: Number of constraints
    :param env_names: A name per env for error messages (e.g. the env id)
    :return: The costs, float32 of shape ``(n_envs, n_costs)``
    """
    costs = np.empty((len(infos), n_costs), dtype=np.float32)
    for env_idx, info in enumerate(infos):
        if key not in info:
            raise CostError(
                f"Environment {env_names[env_idx]!r} (env index {env_idx}) did not report a cost: its info dict has no key "
                f"{key!r} (keys: {sorted(info)}). Put the per-step cost in info[{key!r}] (a float, or one float per "
                "constraint), set `cost_info_key` to the key your env uses, or pass `cost_fn=` to compute costs from "
                "(observation, action)."
            )
        value = info[key]
        if n_costs == 1 and isinstance(value, (float, int, np.floating, np.integer)):
            # The common case, checked in Python: this runs every step, where NumPy's checks cost ~10x more.
            # As a Python float: NumPy would compare a float16 in float16. False for NaN, infinities, negatives and
            # floats that would overflow float32
            cost = float(value)
            if not 0.0 <= cost < FLOAT32_OVERFLOW:
                _check_env_costs(np.array([cost], dtype=np.float64), env_names[env_idx], env_idx)
            costs[env_idx, 0] = cost
        else:
            source = f"Environment {env_names[env_idx]!r} (env index {env_idx}) info[{key!r}]"
            # A scalar or a flat vector: one row for this env (checked by as_cost_array)
            costs[env_idx] = as_cost_array(np.reshape(value, (1, -1)), 1, n_costs, source)[0]
    return costs


def _check_env_costs(costs: np.ndarray, env_name: str, env_idx: int) -> None:
    """Raise a ``CostError`` naming the env if its costs are not finite float32 numbers >= 0."""
    if not np.all(np.isfinite(costs)):
        raise CostError(f"Environment {env_name!r} (env index {env_idx}) reported a non-finite cost: {costs.tolist()}.")
    if np.any(costs < 0):
        raise CostError(
            f"Environment {env_name!r} (env index {env_idx}) reported a negative cost: {costs.tolist()}. A cost "
            "counts violations and must be >= 0 (shift or clip it in the env)."
        )
    if np.any(costs >= FLOAT32_OVERFLOW):
        raise CostError(
            f"Environment {env_name!r} (env index {env_idx}) reported a cost beyond float32's range: {costs.tolist()} "
            f"(costs are stored as float32, up to {float(np.finfo(np.float32).max):.4g}): rescale the cost in the env."
        )
