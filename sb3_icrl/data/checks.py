"""
Semantic checks of demonstrations against the env they are meant for:

- :func:`check_env_id`: the env id recorded with the data is the target env's;
- :func:`dynamics_replay_check` (MuJoCo envs): the data follows the env's dynamics, and each observation is paired
  with the action taken in it. For sampled steps, the simulator is set to the state of ``obs[t]``, steps with
  ``acts[t]`` and the result is compared with ``obs[t + 1]``; the same is done with the actions one step earlier and
  later, so that data whose actions are off by one step (a common slip when converting other codes' files) is named
  as such rather than only failing.

::

    from sb3_icrl.data import load_demonstrations
    from sb3_icrl.data.checks import dynamics_replay_check

    report = dynamics_replay_check(load_demonstrations("BlockedHalfCheetah-v0"), "sb3_icrl/BlockedHalfCheetah-v0")
    print(report)  # mean error per pairing, and the verdict
    assert report.ok
"""

import dataclasses
import warnings
from collections.abc import Callable, Mapping
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env import VecEnv

from sb3_icrl.common.env_ids import resolve_env_id
from sb3_icrl.common.utils import did_you_mean
from sb3_icrl.data.serialize import DemonstrationError
from sb3_icrl.data.types import Demonstrations, Trajectory
from sb3_icrl.envs import NAMESPACE

#: Pairings compared by :func:`dynamics_replay_check`: ``obs[t]`` with ``acts[t + shift]``
SHIFTS = (-1, 0, 1)


def _bare_id(env_id: str) -> str:
    prefix = f"{NAMESPACE}/"
    return env_id[len(prefix) :] if env_id.startswith(prefix) else env_id


def env_id_of(env: gym.Env | VecEnv | str) -> str | None:
    """
    :param env: A registered id, a gymnasium env or a VecEnv
    :return: Its registered id, or ``None`` when it was not made from the registry
    """
    if isinstance(env, str):
        return env
    if isinstance(env, VecEnv):
        try:
            spec = env.get_attr("spec", indices=[0])[0]
        except (AttributeError, IndexError):
            return None
    else:
        spec = env.spec
    return None if spec is None else spec.id


def check_env_id(
    demonstrations: Demonstrations | Mapping[str, Any],
    env: gym.Env | VecEnv | str,
    require_env_id: bool = False,
) -> None:
    """
    Refuse demonstrations recorded on another env than ``env``.

    Ids are compared without the ``sb3_icrl/`` namespace (``BlockedHalfCheetah-v0`` is ``sb3_icrl/BlockedHalfCheetah-v0``)
    but with their version (``-v0`` and ``-v1`` may differ in dynamics or observations).

    :param demonstrations: The demonstrations, or their metadata (the sidecar)
    :param env: The target env: a registered id, a gymnasium env or a VecEnv (an env not made from the registry has
        no id: nothing is compared)
    :param require_env_id: Also refuse data whose metadata records no env id
    :raises DemonstrationError: When the ids differ (or, with ``require_env_id``, when none is recorded)
    """
    metadata = demonstrations.metadata if isinstance(demonstrations, Demonstrations) else demonstrations
    recorded = metadata.get("env_id")
    if recorded is None:
        if require_env_id:
            raise DemonstrationError(
                "The demonstrations do not say which env they were recorded on (no `env_id` in their metadata): add it "
                "(e.g. `from_arrays(..., env_id=...)`), or check them with `dynamics_replay_check` and skip this check."
            )
        return
    target = env_id_of(env)
    if target is None:
        return
    if _bare_id(str(recorded)) != _bare_id(target):
        raise DemonstrationError(
            f"The demonstrations were recorded on {recorded!r}, not on the target env {target!r}: load the dataset made "
            f"for {target!r} (or generate one with `python -m sb3_icrl.data generate --env {_bare_id(target)} ...`)."
        )


@dataclasses.dataclass(frozen=True)
class DynamicsReport:
    """
    Result of :func:`dynamics_replay_check`.

    :param env_id: The env replayed
    :param n_pairs: Steps replayed
    :param errors: ``shift -> mean error`` of the pairing ``obs[t]``, ``acts[t + shift]`` -> ``obs[t + 1]`` (root mean
        square over the observation's entries, averaged over the sampled steps); shift 0 is the data as given
    :param tolerance: Error below which a step counts as following the dynamics
    :param flagged: ``(trajectory, step)`` of the sampled steps whose error, as given, exceeds ``tolerance``
    :param best_shift: The pairing that fits best
    """

    env_id: str | None
    n_pairs: int
    errors: dict[int, float]
    tolerance: float
    flagged: list[tuple[int, int]]
    best_shift: int

    @property
    def mean_error(self) -> float:
        """Mean error of the data as given."""
        return self.errors[0]

    @property
    def flagged_fraction(self) -> float:
        return len(self.flagged) / self.n_pairs

    @property
    def ok(self) -> bool:
        """Whether the data as given follows the dynamics: the given pairing fits best, with a mean error within tolerance."""
        return self.best_shift == 0 and self.mean_error <= self.tolerance

    @property
    def pairing_clear(self) -> bool:
        """Whether the best pairing fits at least ten times better than the other two (so the alignment is not in doubt)."""
        others = [error for shift, error in self.errors.items() if shift != self.best_shift]
        return self.errors[self.best_shift] * 10 <= min(others)

    @property
    def verdict(self) -> str:
        best = self.errors[self.best_shift]
        inexact = (
            "other physics (another env version, MuJoCo version or model file), clipped or normalised observations, "
            "or observations that do not start with qpos and qvel (pass `state_from_obs`)"
        )
        if self.ok:
            return f"aligned: each observation and its action lead to the next observation (mean error {best:.2g})"
        if self.best_shift == 0 and self.pairing_clear:
            return (
                f"aligned (the one-step shifts fit {min(self.errors[-1], self.errors[1]) / max(best, 1e-300):.0f} times "
                f"worse), but the replay is not exact (mean error {best:.2g} > {self.tolerance:g}): {inexact}."
            )
        if self.best_shift != 0 and self.pairing_clear:
            sign = "+" if self.best_shift > 0 else "-"
            exact = "" if best <= self.tolerance else f"; even so the replay is not exact: {inexact}"
            return (
                f"misaligned by one step: obs[t] fits acts[t {sign} 1] (mean error {best:.2g}, against "
                f"{self.mean_error:.2g} as given). Shift the actions (or the observations) when converting the data, "
                f"e.g. for files that store the state after each action in row t{exact}."
            )
        return (
            f"does not follow the env's dynamics (mean error {self.mean_error:.2g} as given, {best:.2g} at best): {inexact}."
        )

    def __str__(self) -> str:
        errors = ", ".join(f"{shift:+d}: {error:.3g}" for shift, error in sorted(self.errors.items()))
        return (
            f"Dynamics replay on {self.env_id or 'the env'} ({self.n_pairs} steps; mean error by action shift {errors}; "
            f"{len(self.flagged)} steps above {self.tolerance:g}): {self.verdict}"
        )


def _is_mujoco(env: gym.Env) -> bool:
    """Whether the env can be set to a state and replayed (a MuJoCo env: ``set_state(qpos, qvel)``)."""
    unwrapped = env.unwrapped
    return hasattr(unwrapped, "set_state") and hasattr(unwrapped, "model") and hasattr(unwrapped.model, "nq")


def _mujoco_env(env: gym.Env | str) -> tuple[gym.Env, Any, bool]:
    """The env, its unwrapped MuJoCo env, and whether it was made here (to be closed)."""
    made = isinstance(env, str)
    environment = gym.make(env) if isinstance(env, str) else env
    unwrapped = environment.unwrapped
    if not _is_mujoco(environment):
        if made:
            environment.close()
        raise DemonstrationError(
            f"The dynamics replay needs a MuJoCo env (with `set_state(qpos, qvel)`), got {type(unwrapped).__name__}."
        )
    return environment, unwrapped, made


def dynamics_replay_check(
    demonstrations: Demonstrations | list[Trajectory],
    env: gym.Env | str,
    n_pairs: int = 200,
    tolerance: float = 1e-4,
    state_from_obs: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]] | None = None,
    seed: int = 0,
) -> DynamicsReport:
    """
    Replay sampled steps of the demonstrations in a MuJoCo env and compare with the recorded next observations.

    For each sampled step ``t`` (with a step before and after it in its trajectory), and each shift ``s`` of
    :data:`SHIFTS`: set the simulator to the state in ``obs[t]``, step with ``acts[t + s]`` and measure the root mean
    square difference between the observation returned and ``obs[t + 1]``. Data recorded on the env itself replays
    to round-off (~1e-12 for float64 observations, ~1e-6 for float32); data whose actions are off by one step fits a
    shifted pairing instead. The env must be deterministic given the state (the benchmark's MuJoCo envs are).

    :param demonstrations: The demonstrations (unnormalised observations)
    :param env: The MuJoCo env or its registered id; the check calls ``reset`` once, then ``set_state`` and ``step``
        on the unwrapped env (an env given is left in an arbitrary state)
    :param n_pairs: Steps to sample (all when there are fewer)
    :param tolerance: Mean error under which the data counts as following the dynamics
    :param state_from_obs: ``obs -> (qpos, qvel)``; default: the observation starts with ``qpos`` then ``qvel`` (the
        benchmark's MuJoCo envs, which keep the position in the observation)
    :param seed: Seed of the sampling
    :return: The report; ``report.ok`` tells whether the data passes
    """
    trajectories = list(demonstrations)
    candidates = [(index, step) for index, trajectory in enumerate(trajectories) for step in range(1, len(trajectory) - 1)]
    if not candidates:
        raise DemonstrationError("The dynamics replay needs trajectories of at least 3 steps.")
    rng = np.random.default_rng(seed)
    chosen = rng.choice(len(candidates), size=min(n_pairs, len(candidates)), replace=False)
    pairs = [candidates[i] for i in sorted(chosen)]
    environment, unwrapped, made = _mujoco_env(env)
    try:
        environment.reset(seed=seed)
        n_qpos, n_qvel = unwrapped.model.nq, unwrapped.model.nv
        obs_dim = int(np.prod(trajectories[0].obs.shape[1:]))
        if state_from_obs is None:
            if obs_dim < n_qpos + n_qvel:
                raise DemonstrationError(
                    f"The observations have {obs_dim} entries, fewer than qpos ({n_qpos}) + qvel ({n_qvel}): they do not "
                    "hold the full state (e.g. the position is excluded). Pass `state_from_obs` to rebuild it."
                )

            def state_from_obs(obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
                flat = np.asarray(obs, dtype=np.float64).reshape(-1)
                return flat[:n_qpos], flat[n_qpos : n_qpos + n_qvel]

        errors: dict[int, list[float]] = {shift: [] for shift in SHIFTS}
        flagged = []
        for index, step in pairs:
            trajectory = trajectories[index]
            target = np.asarray(trajectory.obs[step + 1], dtype=np.float64).reshape(-1)
            for shift in SHIFTS:
                qpos, qvel = state_from_obs(trajectory.obs[step])
                unwrapped.set_state(qpos, qvel)
                observation = unwrapped.step(np.asarray(trajectory.acts[step + shift]))[0]
                error = float(np.sqrt(np.mean((np.asarray(observation, dtype=np.float64).reshape(-1) - target) ** 2)))
                errors[shift].append(error)
                if shift == 0 and not error <= tolerance:
                    flagged.append((index, step))
    finally:
        if made:
            environment.close()
    mean_errors = {shift: float(np.mean(values)) for shift, values in errors.items()}
    best_shift = min(SHIFTS, key=lambda shift: (mean_errors[shift], abs(shift)))
    return DynamicsReport(
        env_id=env_id_of(env) if isinstance(env, (str, gym.Env)) else None,
        n_pairs=len(pairs),
        errors=mean_errors,
        tolerance=tolerance,
        flagged=flagged,
        best_shift=best_shift,
    )


def _opt_out(importer: str) -> str:
    """:return: How to import data with ``importer`` without the checks"""
    return f"pass `check_replay=False` to {importer} to import the data as it is"


def _registered_id(env_id: str, importer: str) -> str | None:
    """
    The registered id of ``env_id`` (``sb3_icrl/`` optional; ``MODULE:EnvId`` imports ``MODULE`` first).

    :param env_id: The env the data is said to come from
    :param importer: The importer's name, for the message
    :return: The id registered with gymnasium; ``None``, with a warning, for an id of other code not registered here
        (the data is then stored unchecked, under that id)
    :raises DemonstrationError: When the id is one of sb3-icrl's that does not exist, or close to one (a typo), or a
        ``MODULE:EnvId`` that does not register ``EnvId``
    """
    if ":" in env_id:
        try:
            return resolve_env_id(env_id)
        except ValueError as error:
            raise DemonstrationError(f"{importer}: {error} Or {_opt_out(importer)}.") from error
    for candidate in (env_id, f"{NAMESPACE}/{env_id}"):
        if candidate in gym.registry:
            return candidate
    ours = sorted(_bare_id(key) for key in gym.registry if key.startswith(f"{NAMESPACE}/"))
    hint = did_you_mean(_bare_id(env_id), ours)  # (compared without the namespace, that all of ours share)
    if hint or env_id.startswith(f"{NAMESPACE}/"):
        raise DemonstrationError(
            f"{importer}: env_id {env_id!r} is not a registered gymnasium env.{hint} Give the id of the env the data "
            "was recorded on, registered first: import the module that registers it (the --gym-packages MODULE of the "
            f"commands) before importing the data, or write the id as MODULE:EnvId; or {_opt_out(importer)}."
        )
    warnings.warn(
        f"{importer}: env_id {env_id!r} is not registered here, so the data is stored under it unchecked (no replay "
        "on its env): to check it, import the module that registers the env first, or write the id as MODULE:EnvId.",
        stacklevel=3,
    )
    return None


def _buildable_env(env_id: str) -> gym.Env | None:
    """The env of the registered ``env_id``, ``None`` when it cannot be built here (its dependencies missing...)."""
    try:
        return gym.make(env_id)
    except Exception:  # (a registered env whose dependencies are missing: nothing to replay on)
        return None


def _check_shapes(demonstrations: Demonstrations, environment: gym.Env, env_id: str | None, importer: str) -> None:
    """
    :raises DemonstrationError: When the observations or actions of a step have another shape than the Box spaces of
        ``environment`` (data of another env; the replay would fail deep in the simulator)
    """
    trajectory = demonstrations.trajectories[0]
    for what, space, values in (
        ("observations", environment.observation_space, trajectory.obs),
        ("actions", environment.action_space, trajectory.acts),
    ):
        if isinstance(space, gym.spaces.Box) and np.shape(values)[1:] != space.shape:
            raise DemonstrationError(
                f"{importer}: the {what} have shape {np.shape(values)[1:]} per step, but {env_id}'s are {space.shape}: the "
                f"data is not from {env_id}; give the env it was recorded on (or none)."
            )


def import_replay_check(demonstrations: Demonstrations, env_id: str | None, importer: str) -> DynamicsReport | None:
    """
    The check the importers run by default: :func:`dynamics_replay_check` on the env the data is said to come from,
    wherever that env can be built here and is a MuJoCo env.

    :param demonstrations: The imported demonstrations
    :param env_id: The env they are said to come from (``None``: nothing to check)
    :param importer: The importer's name, for the messages
    :return: The report, or ``None`` when nothing was replayed (no env id, an env of other code not registered here, an
        env that cannot be built here, not MuJoCo)
    :raises DemonstrationError: When ``env_id`` is one of sb3-icrl's that does not exist or close to one, when the data
        is off by one step, or does not follow the env's dynamics (data of another robot with observations of the
        same shape)
    """
    if env_id is None:
        return None
    registered = _registered_id(env_id, importer)
    environment = None if registered is None else _buildable_env(registered)
    if environment is None:
        return None
    opt_out = _opt_out(importer)
    try:
        _check_shapes(demonstrations, environment, env_id, importer)
        if not _is_mujoco(environment):
            return None
        try:
            report = dynamics_replay_check(demonstrations, environment)
        except DemonstrationError as error:  # (observations without the full state, trajectories too short)
            warnings.warn(f"{importer}: the data was not replayed on {env_id}: {error}", stacklevel=3)
            return None
    finally:
        environment.close()
    if report.ok:
        return report
    if report.best_shift == 0 and report.pairing_clear:
        # Aligned, on slightly other physics (another MuJoCo version or model file): usable, but worth knowing
        warnings.warn(f"{importer}: {report}", stacklevel=3)
        return report
    if report.best_shift != 0 and report.pairing_clear:
        raise DemonstrationError(f"{importer}: {report} Or {opt_out}.")
    raise DemonstrationError(
        f"{importer}: {report} Data recorded on another robot whose observations have the same shape fails so: check "
        f"that it comes from {env_id!r}, or {opt_out}."
    )
