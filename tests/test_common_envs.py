import gymnasium as gym
import numpy as np
import pytest

from sb3_icrl.common.envs import ConstrainedCorridorEnv, VelocityCostWrapper


class ScriptedVelocityEnv(gym.Env):
    """Reports the velocities it is given, one per step, in info["x_velocity"] (or under another key)."""

    observation_space = gym.spaces.Box(-1, 1, shape=(1,))
    action_space = gym.spaces.Box(-1, 1, shape=(1,))

    def __init__(self, velocities, key="x_velocity"):
        self.velocities, self.key, self.t = list(velocities), key, 0

    def reset(self, *, seed=None, options=None):
        self.t = 0
        return np.zeros(1, dtype=np.float32), {}

    def step(self, action):
        self.t += 1
        return np.zeros(1, dtype=np.float32), 0.0, False, False, {self.key: self.velocities[self.t - 1]}


def test_velocity_cost_is_one_strictly_above_the_threshold():
    env = VelocityCostWrapper(ScriptedVelocityEnv([3.0, 3.2096, 3.21, -5.0]))
    env.reset()
    costs = [env.step(np.zeros(1))[4]["cost"] for _ in range(4)]
    assert costs == [0.0, 0.0, 1.0, 0.0]


def test_velocity_cost_needs_the_velocity_key():
    env = VelocityCostWrapper(ScriptedVelocityEnv([1.0], key="speed"))
    env.reset()
    with pytest.raises(KeyError, match="velocity_key="):
        env.step(np.zeros(1))
    wrapped = VelocityCostWrapper(ScriptedVelocityEnv([9.0], key="speed"), velocity_key="speed")
    wrapped.reset()
    assert wrapped.step(np.zeros(1))[4]["cost"] == 1.0


def test_corridor_semantics():
    env = ConstrainedCorridorEnv()
    env.reset(seed=0)
    infos = [env.step(2) for _ in range(20)]
    costs = [info[4]["cost"] for info in infos]
    assert costs == [0.0] * 6 + [1.0] * 14  # cells 7..10 are unsafe, the end is reached at step 10
    assert infos[-1][3] and not any(info[3] for info in infos[:-1]), "truncated after 20 steps only"
    with pytest.raises(ValueError, match="Invalid action"):
        env.step(3)


def test_corridor_renders_and_rejects_unknown_render_modes():
    env = ConstrainedCorridorEnv(render_mode="rgb_array")
    env.reset()
    env.step(2)
    image = env.render()
    assert image.shape == (16, 11 * 16, 3)
    assert tuple(image[0, 16]) == (40, 90, 220) and tuple(image[0, 7 * 16]) == (220, 50, 50)
    with pytest.raises(ValueError, match="render_mode"):
        ConstrainedCorridorEnv(render_mode="human")
