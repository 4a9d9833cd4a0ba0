"""A tiny constrained env for tests and examples: reward pulls right, the cost forbids the far end."""

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sb3_icrl.common.constraint_spec import ConstraintSpec, FeatureConstraint


class ConstrainedCorridorEnv(gym.Env):
    """
    A corridor of cells ``0 .. length - 1``; the agent starts in cell 0 and moves left, stays or moves right.

    Each step pays ``x / (length - 1)`` (further right is better) and costs 1.0 in ``info["cost"]`` when the agent
    stands on a cell ``x > safe_limit``. Unconstrained, the best policy runs to the end and collects a cost almost
    every step; with a small episode budget it must stop at ``safe_limit``. PPO learns it in a few thousand steps.

    Observation: ``[x / (length - 1), t / max_steps]``. Actions: ``0`` left, ``1`` stay, ``2`` right.
    Episodes are truncated after ``max_steps`` steps.

    :param length: Number of cells
    :param safe_limit: Last safe cell; cells to its right cost 1 per step
    :param max_steps: Episode length
    :param render_mode: ``None`` or ``"rgb_array"`` (one row of cells: safe white, unsafe red, agent blue)
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 4}

    @property
    def constraint_spec(self) -> ConstraintSpec:
        """
        The true constraint (see :mod:`sb3_icrl.common.constraint_spec`): ``x / (length - 1) > safe_limit / (length - 1)``;
        the true cost rounds the observed ``x`` back to its cell, so float32 observations of the last safe cell are safe.
        """
        length, safe_limit = self.length, self.safe_limit

        def cell_cost(observations: np.ndarray, actions: np.ndarray | None = None) -> np.ndarray:
            cells = np.rint(np.atleast_2d(observations)[:, 0] * (length - 1))
            return (cells > safe_limit).astype(np.float64)

        return ConstraintSpec(
            features=(FeatureConstraint(0, safe_limit / (length - 1), ">", "x_position"),), cost_fn=cell_cost
        )

    def __init__(self, length: int = 11, safe_limit: int = 6, max_steps: int = 20, render_mode: str | None = None):
        if length < 2 or not 0 <= safe_limit < length - 1:
            raise ValueError(
                f"Need length >= 2 and 0 <= safe_limit < length - 1, got length={length}, safe_limit={safe_limit}."
            )
        if max_steps < 1:
            raise ValueError(f"`max_steps` must be >= 1, got {max_steps}.")
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"Unsupported render_mode {render_mode!r}: use None or 'rgb_array'.")
        self.render_mode = render_mode
        self.length = length
        self.safe_limit = safe_limit
        self.max_steps = max_steps
        self.observation_space = spaces.Box(0.0, 1.0, shape=(2,), dtype=np.float32)
        self.action_space = spaces.Discrete(3)
        self.position = 0
        self.steps = 0

    def _obs(self) -> np.ndarray:
        return np.array([self.position / (self.length - 1), self.steps / self.max_steps], dtype=np.float32)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self.position = 0
        self.steps = 0
        return self._obs(), {"x_position": self.position}

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if not self.action_space.contains(action):
            raise ValueError(f"Invalid action {action!r}: expected 0 (left), 1 (stay) or 2 (right).")
        self.position = int(np.clip(self.position + int(action) - 1, 0, self.length - 1))
        self.steps += 1
        reward = self.position / (self.length - 1)
        cost = float(self.position > self.safe_limit)
        info = {"cost": cost, "x_position": self.position}
        return self._obs(), reward, False, self.steps >= self.max_steps, info

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        cells = np.full((1, self.length, 3), 255, dtype=np.uint8)
        cells[0, self.safe_limit + 1 :] = (220, 50, 50)
        cells[0, self.position] = (40, 90, 220)
        return np.kron(cells, np.ones((16, 16, 1), dtype=np.uint8))
