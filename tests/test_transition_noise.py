"""TransitionNoiseWrapper: noise statistics, seeding, a really perturbed simulator, and a consistent true cost."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gymnasium_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env
from stable_baselines3.common.env_util import make_vec_env

import sb3_icrl.envs  # noqa: F401
from sb3_icrl.envs import TransitionNoiseWrapper


def noisy(name: str, sigma: float, **kwargs) -> TransitionNoiseWrapper:
    return TransitionNoiseWrapper(gym.make(f"sb3_icrl/{name}", **kwargs), sigma)


@pytest.mark.filterwarnings("ignore::UserWarning")
@pytest.mark.parametrize("name", ["BlockedHalfCheetah-v0", "BlockedAnt-v0"])
def test_env_checkers(name):
    gymnasium_check_env(noisy(name, 0.1), skip_render_check=True)
    sb3_check_env(noisy(name, 0.1))


@pytest.mark.parametrize("sigma", [1e-2, 1e-1])
def test_noise_statistics(sigma):
    # HalfCheetah's observation is (qpos, qvel): a noiseless twin shows the noise exactly
    env, twin = noisy("BlockedHalfCheetah-v0", sigma), gym.make("sb3_icrl/BlockedHalfCheetah-v0")
    differences = []
    for seed in range(150):
        env.reset(seed=seed)
        twin.reset(seed=seed)
        action = np.full(6, 0.3)
        obs, *_ = env.step(action)
        clean, *_ = twin.step(action)
        np.testing.assert_allclose(obs - clean, env.last_noise, atol=1e-12)
        differences.append(obs - clean)
    samples = np.concatenate(differences)  # 150 x 18 = 2700 samples
    assert abs(samples.mean()) < 4 * sigma / np.sqrt(samples.size)
    assert samples.std() == pytest.approx(sigma, rel=0.06)
    # Independent components: no correlation between the x noise and the others
    per_component = np.array(differences)
    assert np.all(np.abs(np.corrcoef(per_component.T)[0, 1:]) < 0.3)


def test_same_seed_same_noise():
    def rollout(seed: int) -> np.ndarray:
        env = noisy("BlockedSwimmer-v0", 0.05)
        env.reset(seed=seed)
        return np.array([env.step(np.array([0.5, -0.5]))[0] for _ in range(10)])

    np.testing.assert_array_equal(rollout(5), rollout(5))
    assert not np.allclose(rollout(5), rollout(6))
    # reset(seed) restarts the noise stream
    env = noisy("BlockedSwimmer-v0", 0.05)
    env.reset(seed=5)
    first = [env.step(np.zeros(2))[0] for _ in range(3)]
    env.reset(seed=5)
    np.testing.assert_array_equal(first, [env.step(np.zeros(2))[0] for _ in range(3)])


def test_noise_is_not_the_env_random_stream():
    # Seeding the noise with the reset seed itself would replay the environment's own random stream
    env = noisy("BlockedHalfCheetah-v0", 1.0)
    env.reset(seed=0)
    env.step(np.zeros(6))
    naive = np.random.default_rng(0).normal(0.0, 1.0, size=18)
    assert not np.allclose(env.last_noise, naive)


def test_simulator_state_is_perturbed():
    env, twin = noisy("BlockedWalker-v0", 0.01), gym.make("sb3_icrl/BlockedWalker-v0")
    env.reset(seed=0)
    twin.reset(seed=0)
    obs, *_ = env.step(np.zeros(6))
    np.testing.assert_array_equal(obs[:9], env.unwrapped.data.qpos)
    # The dynamics continue from the perturbed state: a noiseless step of the simulator from there
    qpos, qvel = env.unwrapped.data.qpos.copy(), env.unwrapped.data.qvel.copy()
    twin.step(np.zeros(6))
    twin.unwrapped.set_state(qpos, qvel)
    expected, *_ = twin.step(np.zeros(6))
    env.sigma = 0.0
    obs, *_ = env.step(np.zeros(6))
    np.testing.assert_allclose(obs, expected, atol=1e-12)


def test_cost_follows_the_perturbed_state():
    env = noisy("BlockedHalfCheetah-v0", 0.1)
    env.reset(seed=0)
    costs = []
    for _ in range(100):
        base = env.unwrapped
        qpos = base.init_qpos.copy()
        qpos[0] = -3.0  # on the line: the noise decides on which side the cheetah lands
        base.set_state(qpos, np.zeros(base.model.nv))
        obs, _, _, _, info = env.step(np.zeros(6))
        assert info["x_position"] == obs[0] == base.data.qpos[0]
        assert info["cost"] == float(info["x_position"] <= -3.0)
        costs.append(info["cost"])
    assert 20 < sum(costs) < 80


def test_ant_positions_and_quaternion():
    env = noisy("BlockedAnt-v0", 0.1)
    env.reset(seed=0)
    obs, _, _, _, info = env.step(np.zeros(8))
    qpos = env.unwrapped.data.qpos
    assert np.linalg.norm(qpos[3:7]) == pytest.approx(1.0)
    assert (info["x_position"], info["y_position"]) == (qpos[0], qpos[1]) == (obs[0], obs[1])
    assert info["distance_from_origin"] == pytest.approx(np.hypot(qpos[0], qpos[1]))


def test_observation_noise_on_other_box_envs():
    env, twin = TransitionNoiseWrapper(gym.make("Pendulum-v1"), 0.05), gym.make("Pendulum-v1")
    env.reset(seed=0)
    twin.reset(seed=0)
    obs, *_ = env.step(np.zeros(1))
    clean, *_ = twin.step(np.zeros(1))
    expected = np.clip(clean + env.last_noise, env.observation_space.low, env.observation_space.high)
    np.testing.assert_allclose(obs, expected, rtol=1e-6)
    assert obs.dtype == env.observation_space.dtype and not np.allclose(obs, clean)


def test_zero_sigma_changes_nothing():
    env, twin = noisy("BlockedHalfCheetah-v0", 0.0), gym.make("sb3_icrl/BlockedHalfCheetah-v0")
    env.reset(seed=2)
    twin.reset(seed=2)
    for _ in range(5):
        np.testing.assert_array_equal(env.step(np.ones(6))[0], twin.step(np.ones(6))[0])


@pytest.mark.parametrize("sigma", [-0.1, float("nan"), float("inf")])
def test_bad_sigma(sigma):
    with pytest.raises(ValueError, match="sigma"):
        noisy("BlockedHalfCheetah-v0", sigma)


def test_discrete_env_is_refused():
    with pytest.raises(TypeError, match="Box observation space"):
        TransitionNoiseWrapper(gym.make("sb3_icrl/GridWorld-v0"), 0.1)


def test_observation_wrapper_below_is_refused():
    env = gym.wrappers.NormalizeObservation(gym.make("sb3_icrl/BlockedHalfCheetah-v0"))
    with pytest.raises(ValueError, match="apply TransitionNoiseWrapper first"):
        TransitionNoiseWrapper(env, 0.1)


def test_works_with_make_vec_env():
    def rollout() -> np.ndarray:
        vec_env = make_vec_env(
            "sb3_icrl/BlockedHalfCheetah-v0",
            n_envs=2,
            seed=4,
            wrapper_class=TransitionNoiseWrapper,
            wrapper_kwargs={"sigma": 0.05},
        )
        vec_env.reset()
        return np.array([vec_env.step(np.zeros((2, 6)))[0] for _ in range(5)])

    first = rollout()
    np.testing.assert_array_equal(first, rollout())
    assert not np.allclose(first[:, 0], first[:, 1])


def test_shared_model_adds_one_draw_to_every_component_on_mujoco():
    env, twin = TransitionNoiseWrapper(gym.make("sb3_icrl/BlockedHalfCheetah-v0"), 0.05, model="shared"), gym.make(
        "sb3_icrl/BlockedHalfCheetah-v0"
    )
    env.reset(seed=3)
    twin.reset(seed=3)
    for _ in range(3):
        twin.step(np.full(6, 0.2))
        env.step(np.full(6, 0.2))
        qpos, qvel = env.unwrapped.data.qpos.copy(), env.unwrapped.data.qvel.copy()
        shift = np.concatenate([qpos - twin.unwrapped.data.qpos, qvel - twin.unwrapped.data.qvel])
        np.testing.assert_allclose(shift, np.full(18, shift[0]), atol=1e-12)
        np.testing.assert_allclose(shift, env.last_noise, atol=1e-12)
        assert shift[0] != 0.0
        twin.unwrapped.set_state(qpos, qvel)  # the twin goes on from the same perturbed state


def test_component_model_draws_each_component_apart_on_mujoco():
    env = noisy("BlockedHalfCheetah-v0", 0.05)
    assert env.model == "component"
    env.reset(seed=3)
    env.step(np.zeros(6))
    assert len(np.unique(env.last_noise)) == env.last_noise.size


@pytest.mark.parametrize("model, distinct", [("shared", 1), ("component", 4)])
def test_noise_models_on_a_box_env_without_mujoco(model, distinct):
    # CartPole's bounds (4.8, inf, 0.42 rad, inf) are far from its first states: no clipping blurs the noise
    env, twin = TransitionNoiseWrapper(gym.make("CartPole-v1"), 0.01, model=model), gym.make("CartPole-v1")
    env.reset(seed=1)
    twin.reset(seed=1)
    obs, *_ = env.step(0)
    clean, *_ = twin.step(0)
    noise = obs.astype(np.float64) - clean
    np.testing.assert_allclose(noise, env.last_noise, atol=1e-6)
    assert len(np.unique(np.round(noise, 6))) == distinct


def test_same_seed_same_shared_noise():
    def first_noises(seed: int) -> list[float]:
        env = TransitionNoiseWrapper(gym.make("sb3_icrl/BlockedSwimmer-v0"), 0.05, model="shared")
        env.reset(seed=seed)
        noises = []
        for _ in range(4):
            env.step(np.zeros(2))
            noises.append(float(env.last_noise[0]))
        return noises

    assert first_noises(7) == first_noises(7) != first_noises(8)


@pytest.mark.parametrize("model", ["scalar", "Shared", None])
def test_bad_noise_model(model):
    with pytest.raises(ValueError, match=r"names a transition noise model: 'component' .* or 'shared'"):
        TransitionNoiseWrapper(gym.make("CartPole-v1"), 0.1, model=model)


def test_recorded_noise_of_a_run():
    from sb3_icrl.envs.wrappers import recorded_transition_noise, transition_noise_wrapper

    assert recorded_transition_noise({"transition_noise": 0.01, "transition_noise_model": "shared"}) == (0.01, "shared")
    # Runs recorded before the noise had a model drew it per component
    assert recorded_transition_noise({"transition_noise": 0.01}) == (0.01, "component")
    assert recorded_transition_noise({}) == (0.0, "component")
    assert transition_noise_wrapper(0.0, "shared") is None
    wrap = transition_noise_wrapper(*recorded_transition_noise({"transition_noise": 0.01, "transition_noise_model": "shared"}))
    assert wrap is not None
    env = wrap(gym.make("CartPole-v1"))
    assert isinstance(env, TransitionNoiseWrapper) and (env.sigma, env.model) == (0.01, "shared")
    with pytest.raises(ValueError, match="transition_noise_model"):
        recorded_transition_noise({"transition_noise": 0.01, "transition_noise_model": "scalar"})


def test_identification_episodes_draw_the_noise_of_the_run():
    """The learner's own episodes of the identification probes run under the run's noise model."""
    from sb3_icrl.metrics.identification import policy_pairs

    class Push:
        def predict(self, observation, deterministic=True):
            return np.zeros(len(observation), dtype=np.int64), None

    def observations(sigma: float, model: str) -> np.ndarray:
        return policy_pairs(Push(), "CartPole-v1", n_episodes=1, seed=0, transition_noise=sigma, transition_noise_model=model)[
            0
        ]

    clean = observations(0.0, "component")
    shared, component = observations(0.01, "shared")[: len(clean)], observations(0.01, "component")[: len(clean)]
    # Row 0 is the reset; CartPole's own state is untouched by observation noise, so the episodes stay aligned
    shared_noise, component_noise = (shared - clean)[1:5], (component - clean)[1:5]
    np.testing.assert_allclose(shared_noise, np.repeat(shared_noise[:, :1], 4, axis=1), atol=1e-6)
    assert np.abs(shared_noise).min() > 0
    assert all(len(np.unique(np.round(row, 6))) == 4 for row in component_noise)
