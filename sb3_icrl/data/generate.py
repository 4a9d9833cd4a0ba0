"""
Generate expert demonstrations that respect the true constraint (Liu et al., ICLR 2023, section 3.1): run the
expert, drop the trajectories that break the constraint, stop at the requested count.

Imperfect experts (the paper's 20 / 50 / 80 % settings): with ``violating_fraction = p``, ``round(p * n)``
of the ``n`` kept trajectories are rollouts in which each action was replaced, with probability
``random_action_prob``, by a uniformly random one, and that do break the constraint; the others are clean
expert rollouts. Which slots are violating is drawn at random (seeded), so they are spread over the dataset.
"""

import hashlib
import os
import pathlib
from collections.abc import Callable
from typing import Any, Protocol

import gymnasium as gym
import numpy as np
from stable_baselines3 import PPO, SAC, TD3
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecNormalize

from sb3_icrl.common import env_ids
from sb3_icrl.common.saved import model_damage
from sb3_icrl.common.vec_env import load_vec_normalize
from sb3_icrl.data.serialize import save
from sb3_icrl.data.types import Demonstrations, Trajectory
from sb3_icrl.envs import NAMESPACE
from sb3_icrl.envs.wrappers import DeclaredCostWrapper
from sb3_icrl.pi_lagrangian import PILagrangian
from sb3_icrl.ppo_lagrangian import PPOLagrangian

# Attributes of SB3 algorithms recorded as the expert's hyper-parameters (those it has)
_SB3_HYPERPARAMETERS = (
    "learning_rate",
    "n_steps",
    "batch_size",
    "n_epochs",
    "gamma",
    "gae_lambda",
    "ent_coef",
    "vf_coef",
    "max_grad_norm",
    "target_kl",
    "cost_budget",
    "budget_statistic",
    "cost_gamma",
    "cost_gae_lambda",
    "lagrange_update",
    "lagrange_kwargs",
    "policy_kwargs",
    "seed",
    "num_timesteps",
)
_PI_LAGRANGIAN_HYPERPARAMETERS = (
    "gamma",
    "cost_budget",
    "lagrange_init",
    "lagrange_lr",
    "lagrange_upper_bound",
    "horizon",
    "lagrange_multiplier",
    "num_iterations",
    "seed",
)

#: Algorithms of saved SB3 experts (``.zip``) for :func:`load_expert`
EXPERT_ALGORITHMS: dict[str, type[BaseAlgorithm]] = {"ppolag": PPOLagrangian, "ppo": PPO, "sac": SAC, "td3": TD3}
#: PI-Lagrangian settings of the ``"pilag"`` expert: budget 0, multiplier grown from 0 until the policy is safe
PILAG_EXPERT_KWARGS: dict[str, Any] = {"cost_budget": 0.0, "lagrange_init": 0.0, "lagrange_lr": 0.5}


class Expert(Protocol):
    """Anything with SB3's ``predict``."""

    def predict(
        self,
        observation: Any,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = False,
    ) -> tuple[Any, Any]: ...


class NormalizedExpert:
    """
    An expert trained under ``VecNormalize``: it acts on observations normalised with the frozen statistics,
    while the demonstrations keep the raw observations of the env.

    :param expert: The trained model
    :param vec_normalize: The ``VecNormalize`` wrapper with the training statistics (e.g. from ``VecNormalize.load``)
    """

    def __init__(self, expert: Expert, vec_normalize: VecNormalize):
        self.expert = expert
        self.vec_normalize = vec_normalize
        self.vec_normalize.training = False

    def predict(
        self,
        observation: Any,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = False,
    ) -> tuple[Any, Any]:
        normalized = self.vec_normalize.normalize_obs(observation)
        return self.expert.predict(normalized, state=state, episode_start=episode_start, deterministic=deterministic)


def json_safe(value: Any) -> Any:
    """
    :param value: Any value
    :return: The value with numpy scalars and arrays, tuples and unknown objects turned into JSON types (objects by ``repr``)
    """
    if isinstance(value, (bool, str, int, float)) or value is None:
        return value
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, dict):
        return {str(key): json_safe(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(item) for item in value]
    return repr(value)


def describe_expert(expert: Any) -> dict[str, Any]:
    """
    :param expert: The expert (PILagrangian, an SB3 algorithm, or a :class:`NormalizedExpert` around one)
    :return: Its algorithm name and the hyper-parameters it exposes, JSON-safe
    """
    normalized = isinstance(expert, NormalizedExpert)
    model = expert.expert if normalized else expert
    names = _PI_LAGRANGIAN_HYPERPARAMETERS if type(model).__name__ == "PILagrangian" else _SB3_HYPERPARAMETERS
    hyperparameters = {name: json_safe(getattr(model, name)) for name in names if hasattr(model, name)}
    return {"algorithm": type(model).__name__, "hyperparameters": hyperparameters, "vec_normalize": normalized}


def _step_cost(info: dict[str, Any], cost_info_key: str) -> np.ndarray:
    if cost_info_key not in info:
        raise KeyError(f"Demonstrations need the true cost in info[{cost_info_key!r}]; the env reports {sorted(info)}.")
    return np.asarray(info[cost_info_key], dtype=np.float32)


def rollout_trajectory(
    policy: Callable[[Any], Any],
    env: gym.Env,
    cost_info_key: str = "cost",
    keep_infos: bool = False,
    seed: int | None = None,
) -> Trajectory:
    """
    Run one episode.

    :param policy: Maps an observation to the action to take
    :param env: A gymnasium env whose episodes end (terminated or truncated)
    :param cost_info_key: Info key of the true per-step cost
    :param keep_infos: Keep the info dicts in the trajectory
    :param seed: Seed of the reset (``None``: continue the env's random stream)
    :return: The trajectory
    """
    observation, _ = env.reset(seed=seed)
    observations, actions, rewards, costs, infos = [np.asarray(observation)], [], [], [], []
    terminated = truncated = False
    while not (terminated or truncated):
        action = np.asarray(policy(observation))
        observation, reward, terminated, truncated, info = env.step(action)
        observations.append(np.asarray(observation))
        actions.append(action)
        rewards.append(reward)
        costs.append(_step_cost(info, cost_info_key))
        if keep_infos:
            infos.append(info)
    return Trajectory(
        obs=np.stack(observations),
        acts=np.stack(actions),
        infos=np.array(infos, dtype=object) if keep_infos else None,
        terminal=bool(terminated),
        rews=np.asarray(rewards, dtype=np.float32),
        costs=np.stack(costs),
    )


def generate_demonstrations(
    expert: Expert,
    env: gym.Env | str,
    n_trajectories: int,
    deterministic: bool = True,
    violating_fraction: float = 0.0,
    random_action_prob: float = 0.5,
    seed: int | None = None,
    max_attempts: int | None = None,
    cost_info_key: str = "cost",
    keep_infos: bool = False,
) -> Demonstrations:
    """
    Roll out the expert and keep ``n_trajectories`` trajectories: clean ones break no true constraint; with
    ``violating_fraction > 0``, exactly ``round(violating_fraction * n_trajectories)`` of them are perturbed
    rollouts (random actions injected) that do break it.

    :param expert: The expert (anything with SB3's ``predict``; see :class:`NormalizedExpert` for ``VecNormalize``)
    :param env: A single gymnasium env with the true cost in ``info[cost_info_key]``, or a registered id (an env made
        here gets the cost of its declared constraint where it reports none, see
        :class:`~sb3_icrl.envs.wrappers.DeclaredCostWrapper`)
    :param n_trajectories: Trajectories to keep
    :param deterministic: Deterministic expert actions (the paper's setting)
    :param violating_fraction: Share of kept trajectories that must contain violating state-action pairs, in [0, 1]
    :param random_action_prob: In perturbed rollouts, the probability that each action is replaced by a random one
    :param seed: Seed of the first reset, the random actions and the choice of the violating slots
    :param max_attempts: Episodes to try before giving up; ``None``: ``20 * n_trajectories + 100``
    :param cost_info_key: Info key of the true per-step cost
    :param keep_infos: Keep each step's info dict (they are pickled into the file's ``infos``)
    :return: The trajectories, with generation statistics and the expert's description as metadata
    """
    if isinstance(env, VecEnv):
        raise TypeError(
            "Pass a single gymnasium env or an env id (for VecNormalize statistics wrap the expert in NormalizedExpert)."
        )
    if n_trajectories < 1:
        raise ValueError(f"`n_trajectories` must be >= 1, got {n_trajectories}.")
    if not 0.0 <= violating_fraction <= 1.0:
        raise ValueError(f"`violating_fraction` is a share of trajectories in [0, 1], got {violating_fraction}.")
    if not 0.0 <= random_action_prob <= 1.0 or (random_action_prob == 0 and violating_fraction > 0):
        raise ValueError(
            f"`random_action_prob` is a probability in [0, 1], > 0 to inject violations; got {random_action_prob}."
        )
    if seed is not None and not (isinstance(seed, (int, np.integer)) and seed >= 0):
        raise ValueError(f"`seed` must be an integer >= 0 or None, got {seed!r}.")
    if max_attempts is not None and max_attempts < n_trajectories:
        raise ValueError(f"`max_attempts` ({max_attempts}) must be at least the {n_trajectories} trajectories to keep.")
    max_attempts = 20 * n_trajectories + 100 if max_attempts is None else max_attempts
    made_here = isinstance(env, str)
    if isinstance(env, str):
        # The true cost of a declared constraint when the env does not report one itself
        env = DeclaredCostWrapper(gym.make(env), cost_info_key=cost_info_key)
    rng = np.random.default_rng(seed)
    env.action_space.seed(seed)

    n_violating = round(violating_fraction * n_trajectories)
    violating_slots = np.zeros(n_trajectories, dtype=bool)
    violating_slots[:n_violating] = True
    rng.shuffle(violating_slots)

    def expert_action(observation: Any) -> Any:
        return expert.predict(observation, deterministic=deterministic)[0]

    def perturbed_action(observation: Any) -> Any:
        if rng.random() < random_action_prob:
            return env.action_space.sample()
        return expert_action(observation)

    counts = {"expert_episodes": 0, "expert_violating_episodes": 0, "perturbed_episodes": 0, "perturbed_without_violation": 0}
    trajectories: list[Trajectory] = []
    attempts = 0
    try:
        for wants_violation in violating_slots:
            while True:
                if attempts >= max_attempts:
                    raise RuntimeError(_give_up_message(len(trajectories), n_trajectories, attempts, counts))
                policy = perturbed_action if wants_violation else expert_action
                # Only the first reset is seeded: later episodes continue the env's random stream
                trajectory = rollout_trajectory(policy, env, cost_info_key, keep_infos, seed=seed if attempts == 0 else None)
                attempts += 1
                kind = "perturbed" if wants_violation else "expert"
                counts[f"{kind}_episodes"] += 1
                if trajectory.violates == wants_violation:
                    trajectories.append(trajectory)
                    break
                counts["perturbed_without_violation" if wants_violation else "expert_violating_episodes"] += 1
    finally:
        if made_here:
            env.close()

    spec = env.spec
    generation = {
        "n_requested": n_trajectories,
        "violating_fraction": violating_fraction,
        "n_violating_requested": n_violating,
        "random_action_prob": random_action_prob if n_violating > 0 else None,
        "deterministic": deterministic,
        "cost_info_key": cost_info_key,
        **counts,
        "expert_violation_rate": counts["expert_violating_episodes"] / max(counts["expert_episodes"], 1),
    }
    metadata = {
        "env_id": None if spec is None else spec.id,
        "env_kwargs": {} if spec is None else json_safe(spec.kwargs),
        "max_episode_steps": None if spec is None else spec.max_episode_steps,
        "seed": seed,
        "expert": describe_expert(expert),
        "generation": generation,
    }
    return Demonstrations(trajectories, metadata)


def _give_up_message(n_kept: int, n_requested: int, attempts: int, counts: dict[str, int]) -> str:
    message = f"Kept only {n_kept} of {n_requested} trajectories after {attempts} episodes"
    if counts["expert_episodes"]:
        rate = counts["expert_violating_episodes"] / counts["expert_episodes"]
        message += (
            f"; the expert broke the true constraint in {rate:.0%} of its episodes (train it longer or with a lower budget)"
        )
    if counts["perturbed_episodes"]:
        rate = counts["perturbed_without_violation"] / counts["perturbed_episodes"]
        message += f"; {rate:.0%} of the perturbed episodes stayed safe (raise `random_action_prob`)"
    return message + ". Raise `max_attempts` to keep trying."


def resolve_env_id(name: str) -> str:
    """
    :param name: A registered id, a benchmark name without the namespace (``"GridWorldWall-v0"``), or gymnasium's
        ``MODULE:EnvId`` (the module is imported: it registers the env)
    :return: The registered id
    """
    if ":" in name:
        return env_ids.resolve_env_id(name)
    if name in gym.registry:
        return name
    namespaced = f"{NAMESPACE}/{name}"
    if namespaced in gym.registry:
        return namespaced
    ours = sorted(env_id for env_id in gym.registry if env_id.startswith(f"{NAMESPACE}/"))
    raise ValueError(f"Unknown env {name!r}: give a registered gymnasium id, e.g. one of {ours}.")


def portable_path(path: str | os.PathLike) -> str:
    """Files shipped in the package are recorded relative to it (``sb3_icrl/data/experts/...``): same on every machine."""
    package_root = pathlib.Path(__file__).resolve().parents[2]
    resolved = pathlib.Path(path).resolve()
    if resolved.is_relative_to(package_root / "sb3_icrl"):
        return resolved.relative_to(package_root).as_posix()
    return os.fspath(path)


def file_sha256(path: str | os.PathLike) -> str:
    return hashlib.sha256(pathlib.Path(path).read_bytes()).hexdigest()


def _damaged_expert(expert: str, damage: str) -> ValueError:
    """
    :param expert: The expert's file
    :param damage: What is wrong with it (:func:`~sb3_icrl.common.saved.model_damage`)
    :return: The error that names both
    """
    return ValueError(f"The expert {expert} {damage}: train it again, or give another saved model.")


def load_expert(
    expert: str,
    env_id: str,
    env_kwargs: dict[str, Any] | None = None,
    algo: str = "ppolag",
    vec_normalize_path: str | None = None,
    seed: int | None = None,
) -> tuple[Expert, dict[str, Any]]:
    """
    Build or load an expert.

    :param expert: ``"pilag"`` (train PI-Lagrangian on the env's tables, seconds), a PILagrangian ``.npz``, or an SB3 ``.zip``
    :param env_id: The registered env id
    :param env_kwargs: Keyword arguments of ``gym.make``
    :param algo: For ``.zip`` files: the algorithm, one of :data:`EXPERT_ALGORITHMS`
    :param vec_normalize_path: Optional ``VecNormalize`` statistics saved during the expert's training
    :param seed: Seed of the PI-Lagrangian tie-breaking
    :return: The expert and its description for the metadata (algorithm, hyper-parameters, file and its sha256)
    """
    env_kwargs = env_kwargs or {}
    source: dict[str, Any] = {"path": None, "sha256": None}
    model: Any
    if expert == "pilag":
        model = PILagrangian(gym.make(env_id, **env_kwargs), seed=seed, **PILAG_EXPERT_KWARGS).learn()
    else:
        if not os.path.isfile(expert):
            raise FileNotFoundError(f"No expert file at {expert!r}: give a saved model (.zip, .npz) or 'pilag'.")
        source = {"path": portable_path(expert), "sha256": file_sha256(expert)}
        # The zip's entries and checksums only: SB3's load below unpacks the model, once
        damage = None if expert.endswith(".npz") else model_damage(expert, load=False)
        if damage is not None:  # SB3's own error would name neither the file nor what is wrong with it
            raise _damaged_expert(expert, damage)
        if expert.endswith(".npz"):
            model = PILagrangian.load(expert)
        elif algo in EXPERT_ALGORITHMS:
            try:
                model = EXPERT_ALGORITHMS[algo].load(expert, device="cpu")
            except Exception as error:
                damage = model_damage(expert)  # unpacked again only to name a broken entry (JSON, pickle, tensor)
                if damage is None:
                    raise
                raise _damaged_expert(expert, damage) from error
        else:
            raise ValueError(f"Unknown expert algorithm {algo!r}: choose one of {sorted(EXPERT_ALGORITHMS)}.")
    if vec_normalize_path is not None:
        venv = DummyVecEnv([lambda: gym.make(env_id, **env_kwargs)])
        model = NormalizedExpert(model, load_vec_normalize(vec_normalize_path, venv))
        source["vec_normalize_path"] = portable_path(vec_normalize_path)
        source["vec_normalize_sha256"] = file_sha256(vec_normalize_path)
    return model, {**describe_expert(model), **source}


def build_dataset(
    out: str | os.PathLike,
    env: str,
    expert: str,
    n_trajectories: int,
    env_kwargs: dict[str, Any] | None = None,
    algo: str = "ppolag",
    vec_normalize_path: str | None = None,
    command: str | None = None,
    **generate_kwargs: Any,
) -> dict[str, Any]:
    """
    Load (or train) the expert, generate the demonstrations and save them with their metadata: what the CLI runs.

    :param out: Destination ``.npz``
    :param env: Env id or benchmark name
    :param expert: See :func:`load_expert`
    :param n_trajectories: Trajectories to keep
    :param env_kwargs: Keyword arguments of ``gym.make``
    :param algo: See :func:`load_expert`
    :param vec_normalize_path: See :func:`load_expert`
    :param command: The command line that regenerates the file (stored in the metadata)
    :param generate_kwargs: Passed to :func:`generate_demonstrations` (``violating_fraction``, ``seed``, ...)
    :return: The sidecar's content
    """
    env_id = resolve_env_id(env)
    env_kwargs = env_kwargs or {}
    model, expert_info = load_expert(expert, env_id, env_kwargs, algo, vec_normalize_path, generate_kwargs.get("seed"))
    cost_info_key = generate_kwargs.get("cost_info_key", "cost")
    gym_env = DeclaredCostWrapper(gym.make(env_id, **env_kwargs), cost_info_key=cost_info_key)
    try:
        demonstrations = generate_demonstrations(model, gym_env, n_trajectories, **generate_kwargs)
    finally:
        gym_env.close()
    metadata = {**demonstrations.metadata, "expert": expert_info, "command": command}
    return save(out, demonstrations.trajectories, metadata)
