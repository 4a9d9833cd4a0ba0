"""ShallowCopyDummyVecEnv: the same steps as SB3's DummyVecEnv, without deep copies."""

import gymnasium as gym
import numpy as np
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv

import sb3_icrl.envs  # noqa: F401  (registers the environments)
from sb3_icrl.common.vec_env import ShallowCopyDummyVecEnv


def make_envs(cls):
    # Pendulum episodes end early and at different steps: auto-resets, terminal observations, Monitor's episode info
    return cls([lambda: Monitor(gym.make("sb3_icrl/BiasedPendulum-v0")) for _ in range(3)])


def test_steps_equal_dummy_vec_envs():
    reference, shallow = make_envs(DummyVecEnv), make_envs(ShallowCopyDummyVecEnv)
    reference.seed(0)
    shallow.seed(0)
    np.testing.assert_array_equal(reference.reset(), shallow.reset())
    rng = np.random.default_rng(0)
    ended = 0
    for _ in range(60):
        actions = rng.uniform(-3, 3, size=(3, 1)).astype(np.float32)
        expected, got = reference.step(actions), shallow.step(actions)
        for want, have in zip(expected[:3], got[:3], strict=True):
            np.testing.assert_array_equal(want, have)
        for want, have in zip(expected[3], got[3], strict=True):
            assert want.keys() == have.keys()
            for key in want:
                if key == "episode":
                    assert want[key]["r"] == have[key]["r"] and want[key]["l"] == have[key]["l"]
                else:
                    np.testing.assert_array_equal(want[key], have[key])
        ended += int(np.sum(got[2]))
    assert ended > 3, "the steps must cover episode ends"


def test_returned_observations_and_infos_are_the_callers_own():
    venv = make_envs(ShallowCopyDummyVecEnv)
    venv.reset()
    obs, _, _, infos = venv.step(np.zeros((3, 1), dtype=np.float32))
    kept = obs.copy()
    assert all(info is not buffered for info, buffered in zip(infos, venv.buf_infos, strict=True))
    venv.step(np.ones((3, 1), dtype=np.float32))
    np.testing.assert_array_equal(obs, kept)  # not the env's buffer, which the step refilled
