"""The benchmark's MuJoCo environments: registration, API checks, observations, constraints and rewards."""

import pickle

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gymnasium_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import sb3_icrl.envs
from sb3_icrl.envs import CONSTRAINED_FEATURE, ENV_SPECS

# id -> (observation size, episode length)
EXPECTED = {
    "BlockedHalfCheetah-v0": (18, 1000),
    "BlockedAnt-v0": (107, 500),
    "BiasedPendulum-v0": (4, 100),
    "BlockedWalker-v0": (18, 500),
    "BlockedSwimmer-v0": (10, 500),
}
ENV_IDS = list(EXPECTED)


def make(name: str, **kwargs) -> gym.Env:
    return gym.make(f"sb3_icrl/{name}", **kwargs)


def place(env: gym.Env, x: float, x_velocity: float = 0.0, y: float | None = None) -> None:
    """Put the robot at ``x`` (and ``y``) in its initial pose, at rest apart from ``x_velocity``."""
    base = env.unwrapped
    qpos, qvel = base.init_qpos.copy(), np.zeros_like(base.init_qvel)
    qpos[0], qvel[0] = x, x_velocity
    if y is not None:
        qpos[1] = y
    base.set_state(qpos, qvel)


def test_registration_is_idempotent():
    before = {name: gym.spec(f"sb3_icrl/{name}") for name in ENV_SPECS}
    sb3_icrl.envs.register_envs()
    sb3_icrl.envs.register_envs()
    assert all(gym.spec(f"sb3_icrl/{name}") is spec for name, spec in before.items())
    assert set(CONSTRAINED_FEATURE) == set(ENV_IDS)


@pytest.mark.filterwarnings("ignore:.*(infinity|symmetric and normalized).*:UserWarning")
@pytest.mark.parametrize("name", ENV_IDS)
def test_env_checkers(name):
    env = make(name)
    gymnasium_check_env(env.unwrapped, skip_render_check=True)
    sb3_check_env(env)


@pytest.mark.parametrize("name", ENV_IDS)
def test_observation_and_episode_length(name):
    obs_size, episode_length = EXPECTED[name]
    env = make(name)
    assert env.observation_space.shape == (obs_size,)
    assert env.spec.max_episode_steps == episode_length
    obs, _ = env.reset(seed=0)
    assert obs.shape == (obs_size,)
    # The documented index holds the constrained quantity, in the observation and in info
    feature = CONSTRAINED_FEATURE[name]
    place(env, x=0.3)
    obs, _, _, _, info = env.step(np.zeros(env.action_space.shape))
    assert obs[feature.obs_index] == pytest.approx(info[feature.name]) == pytest.approx(env.unwrapped.data.qpos[0])
    assert abs(info[feature.name] - 0.3) < 0.05


@pytest.mark.parametrize("name", ENV_IDS)
def test_seeded_resets_are_reproducible(name):
    def rollout(seed: int) -> np.ndarray:
        env = make(name)
        env.action_space.seed(123)
        observations = [env.reset(seed=seed)[0]]
        for _ in range(20):
            obs, _, terminated, truncated, _ = env.step(env.action_space.sample())
            observations.append(obs)
            if terminated or truncated:
                break
        return np.array(observations)

    first, second, other = rollout(7), rollout(7), rollout(8)
    np.testing.assert_array_equal(first, second)
    assert not np.allclose(first[0], other[0])


@pytest.mark.parametrize("name", ENV_IDS)
def test_constraint_semantics(name):
    feature = CONSTRAINED_FEATURE[name]
    env = make(name)
    env.reset(seed=0)
    # Past the line (by a margin much larger than one step's motion) costs 1, inside costs 0
    margin = 0.01 if name == "BiasedPendulum-v0" else 0.5
    sign = -1.0 if feature.op == "<=" else 1.0
    for x, expected_cost in ((feature.threshold + sign * margin, 1.0), (feature.threshold - sign * margin, 0.0)):
        place(env, x)
        _, _, _, _, info = env.step(np.zeros(env.action_space.shape))
        assert info["cost"] == expected_cost, (x, info)
        assert isinstance(info["cost"], float)
    # The boundary itself is forbidden
    base = env.unwrapped
    assert base.constraint_cost(feature.threshold) == 1.0
    assert base.constraint_cost(feature.threshold - sign * 1e-6) == 0.0


@pytest.mark.parametrize("name", ENV_IDS)
def test_threshold_is_a_constructor_argument(name):
    feature = CONSTRAINED_FEATURE[name]
    # Move the line towards the origin, then stand where the default line would allow
    env = make(name, cost_threshold=feature.threshold / 2)
    env.reset(seed=0)
    place(env, 0.75 * feature.threshold)
    assert env.step(np.zeros(env.action_space.shape))[4]["cost"] == 1.0
    assert make(name).unwrapped.constraint_cost(0.75 * feature.threshold) == 0.0


def test_cheetah_swimmer_walker_rewards():
    action_scale = {"BlockedHalfCheetah-v0": 0.1, "BlockedSwimmer-v0": 1e-4, "BlockedWalker-v0": 1e-3}
    for name, ctrl_weight in action_scale.items():
        env = make(name)
        env.reset(seed=0)
        # Moving backwards: the reward must pay the speed, not the signed velocity
        place(env, x=0.0, x_velocity=-2.0)
        x_before = env.unwrapped.data.qpos[0]
        action = np.full(env.action_space.shape, 0.5)
        _, reward, _, _, info = env.step(action)
        dx = info["x_position"] - x_before
        assert dx < -1e-3
        expected = abs(dx) / env.unwrapped.dt - ctrl_weight * np.sum(action**2)
        if name == "BlockedWalker-v0":
            expected += 1.0
        assert reward == pytest.approx(expected, rel=1e-9), name


def test_ant_reward():
    env = make("BlockedAnt-v0")
    env.reset(seed=0)
    place(env, x=2.0, y=-1.0)
    action = np.full(env.action_space.shape, 0.3)
    _, reward, terminated, _, _ = env.step(action)
    data = env.unwrapped.data
    distance = np.hypot(data.qpos[0], data.qpos[1])
    contact_cost = 5e-4 * np.sum(np.square(np.clip(data.cfrc_ext, -1.0, 1.0)))
    healthy = 1.0 if 0.2 <= data.qpos[2] <= 1.0 else 0.0
    assert distance > 2.0 and healthy == 1.0
    assert reward == pytest.approx(distance + healthy - 0.5 * np.sum(action**2) - contact_cost, rel=1e-9)
    assert not terminated
    # As the paper's code, a fallen ant keeps going (no termination when unhealthy)
    assert not env.unwrapped._terminate_when_unhealthy


@pytest.mark.parametrize("x, expected", [(-0.05, 1.0), (-0.01, 1.0), (-0.005, 0.55), (-0.0025, 0.325), (0.0, 0.1), (0.2, 0.1)])
def test_pendulum_reward_definition(x, expected):
    assert make("BiasedPendulum-v0").unwrapped.biased_reward(x) == pytest.approx(expected)


def test_pendulum_step_reward_and_termination():
    env = make("BiasedPendulum-v0")
    env.reset(seed=0)
    for x in (-0.012, -0.004, 0.05):
        place(env, x)
        _, reward, terminated, _, info = env.step(np.zeros(1))
        x_after = info["x_position"]
        expected = 1.0 if x_after <= -0.01 else 0.1 if x_after >= 0 else 0.1 + 0.9 * x_after / -0.01
        assert reward == pytest.approx(expected) and not terminated
    # The pole falls: the episode ends, and the reward of that step is still paid
    qpos = env.unwrapped.init_qpos.copy()
    qpos[:] = (-0.02, 0.5)
    env.unwrapped.set_state(qpos, np.zeros(2))
    _, reward, terminated, _, _ = env.step(np.zeros(1))
    assert terminated and reward == 1.0


def test_walker_terminates_when_fallen():
    env = make("BlockedWalker-v0")
    env.reset(seed=0)
    qpos = env.unwrapped.init_qpos.copy()
    qpos[1] = 0.5  # torso below the healthy height
    env.unwrapped.set_state(qpos, np.zeros_like(env.unwrapped.init_qvel))
    assert env.step(np.zeros(6))[2]


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"exclude_current_positions_from_observation": True}, "position in the observation"),
        ({"cost_threshold": float("nan")}, "cost_threshold"),
    ],
)
def test_bad_arguments(kwargs, message):
    with pytest.raises(ValueError, match=message):
        make("BlockedHalfCheetah-v0", **kwargs)


def test_bad_pendulum_ramp():
    with pytest.raises(ValueError, match="high_reward_x"):
        make("BiasedPendulum-v0", high_reward_x=0.01)


def test_pickle_keeps_arguments():
    env = make("BlockedSwimmer-v0", cost_threshold=0.25).unwrapped
    clone = pickle.loads(pickle.dumps(env))
    assert type(clone) is type(env) and clone.cost_threshold == 0.25 and clone.cost_op == ">="
