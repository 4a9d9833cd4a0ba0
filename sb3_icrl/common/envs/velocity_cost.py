"""Safety-Gymnasium style velocity constraint for gymnasium's MuJoCo locomotion envs."""

from typing import Any, SupportsFloat

import gymnasium as gym

#: Safety-Gymnasium's velocity thresholds (safety_gymnasium/tasks/safe_velocity), in m/s
SAFETY_GYMNASIUM_VELOCITY_THRESHOLDS = {
    "HalfCheetah": 3.2096,
    "Hopper": 0.7402,
    "Walker2d": 2.3415,
    "Ant": 2.6222,
    "Humanoid": 1.4149,
    "Swimmer": 0.2282,
}


class VelocityCostWrapper(gym.Wrapper):
    """
    Adds ``info["cost"] = 1.0`` when the robot moves faster than a threshold, as in Safety-Gymnasium's
    velocity tasks (``SafetyHalfCheetahVelocity-v1``: cost 1 when ``x_velocity > 3.2096``).

    :param env: A MuJoCo locomotion env whose ``info`` reports the velocity (gymnasium v5: ``x_velocity``)
    :param velocity_threshold: Speed above which a step costs 1
    :param velocity_key: The info key holding the velocity
    """

    def __init__(self, env: gym.Env, velocity_threshold: float = 3.2096, velocity_key: str = "x_velocity"):
        super().__init__(env)
        self.velocity_threshold = velocity_threshold
        self.velocity_key = velocity_key

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        if self.velocity_key not in info:
            env_name = self.env.spec.id if self.env.spec else self.env
            raise KeyError(
                f"VelocityCostWrapper needs info[{self.velocity_key!r}] from {env_name}, which reports {sorted(info)}: "
                "pass `velocity_key=` with the key your env uses."
            )
        info["cost"] = float(info[self.velocity_key] > self.velocity_threshold)
        return obs, reward, terminated, truncated, info
