"""
Grid world of the ICRL benchmark (Liu et al., ICLR 2023, appendix "Discrete Environments").

A 7x7 grid, 8 king moves, start in the top-left cell, a goal, and a set of unsafe cells that the
expert avoids. Entering the goal pays ``goal_reward`` and ends the episode; every step that ends in an
unsafe cell costs 1 (``info["cost"]``) and does not end it. Episodes are cut at 50 steps by the registration.

The four named maps are the paper's four settings (public code, ``WGW-setting1..4.yaml``); cells are
``(row, column)`` with row 0 at the top, ``S`` start, ``G`` goal, ``X`` unsafe, ``.`` free:

========================  ==========  ============================================  ==========
name                      paper       unsafe cells                                  goal
========================  ==========  ============================================  ==========
``"wall"``                setting 1   row 3, columns 0-4 (5 cells)                  (6, 0)
``"square"``              setting 2   rows 2-4 x columns 2-4 (9 cells)              (6, 6)
``"big-square"``          setting 3   rows 1-5 x columns 1-5 (25 cells)             (6, 6)
``"zigzag"``              setting 4   row 2 columns 0-4, row 4 columns 2-6 (10)     (6, 6)
========================  ==========  ============================================  ==========

Every shortest path from start to goal crosses unsafe cells on each of them, so a safe agent must detour.
A map of your own is a list of equal-length strings over ``S G X .`` (``desc=[...]``).

Observations are the index of the agent's cell, ``row * n_cols + col``, in a ``Discrete`` space:
SB3 one-hot encodes them for its policies. :meth:`GridWorldEnv.state_to_cell` converts back.

The dynamics are exposed as tables for dynamic programming (:class:`~sb3_icrl.pi_lagrangian.PILagrangian`):
``P[s, a, s']`` transition probabilities, ``R[s, a]`` expected reward, ``C[s, a]`` expected true cost.
With ``slip_prob = p`` the intended move is replaced, with probability ``p``, by one of the 8 moves drawn
uniformly. A move off the grid leaves the agent in place. The goal is absorbing, with no reward or cost.
"""

from collections.abc import Sequence
from typing import Any

import numpy as np
from gymnasium import Env, spaces

from sb3_icrl.common.constraint_spec import ConstraintSpec

#: King moves as ``(d_row, d_col)``: right, left, down, up, down-right, up-right, down-left, up-left
ACTIONS = np.array([(0, 1), (0, -1), (1, 0), (-1, 0), (1, 1), (-1, 1), (1, -1), (-1, -1)], dtype=np.int64)
ACTION_NAMES = ("right", "left", "down", "up", "down-right", "up-right", "down-left", "up-left")

#: The paper's four constraint maps (see the module docstring)
MAPS: dict[str, tuple[str, ...]] = {
    "wall": (
        "S......",
        ".......",
        ".......",
        "XXXXX..",
        ".......",
        ".......",
        "G......",
    ),
    "square": (
        "S......",
        ".......",
        "..XXX..",
        "..XXX..",
        "..XXX..",
        ".......",
        "......G",
    ),
    "big-square": (
        "S......",
        ".XXXXX.",
        ".XXXXX.",
        ".XXXXX.",
        ".XXXXX.",
        ".XXXXX.",
        "......G",
    ),
    "zigzag": (
        "S......",
        ".......",
        "XXXXX..",
        ".......",
        "..XXXXX",
        ".......",
        "......G",
    ),
}


def parse_map(desc: Sequence[str]) -> tuple[tuple[int, int], tuple[int, int], np.ndarray]:
    """
    Read a map given as strings over ``S G X .``.

    :param desc: One string per row, all of the same length
    :return: Start cell, goal cell, and the boolean ``(n_rows, n_cols)`` mask of unsafe cells
    """
    if isinstance(desc, str) or len(desc) == 0:
        raise ValueError(f"A grid map is a non-empty list of strings (one per row), got {desc!r}.")
    rows = [str(row) for row in desc]
    if len({len(row) for row in rows}) != 1 or len(rows[0]) == 0:
        raise ValueError(f"Every row of a grid map must have the same, non-zero length; got lengths {[len(r) for r in rows]}.")
    grid = np.array([list(row) for row in rows])
    unknown = sorted(set(grid.flat) - set("SGX."))
    if unknown:
        raise ValueError(f"Unknown map characters {unknown}: use 'S' start, 'G' goal, 'X' unsafe, '.' free.")
    for char, what in (("S", "start"), ("G", "goal")):
        count = int(np.sum(grid == char))
        if count != 1:
            raise ValueError(f"A grid map needs exactly one '{char}' ({what} cell), found {count}.")
    start = tuple(int(i) for i in np.argwhere(grid == "S")[0])
    goal = tuple(int(i) for i in np.argwhere(grid == "G")[0])
    return start, goal, grid == "X"  # type: ignore[return-value]


class GridWorldEnv(Env):
    """
    Grid world with unsafe cells (ids ``sb3_icrl/GridWorld-v0`` and one per named map, 50 steps).

    :param map_name: One of :data:`MAPS` (default ``"wall"``); leave ``None`` when giving ``desc``
    :param desc: A map of your own, one string per row over ``S`` start, ``G`` goal, ``X`` unsafe, ``.`` free
    :param slip_prob: Probability that the move is replaced by a uniformly random one (0: deterministic)
    :param goal_reward: Reward for entering the goal
    :param render_mode: ``None``, ``"ansi"`` (text) or ``"rgb_array"`` (an image: free cells white, unsafe red,
        goal green, agent blue; SB3 asks for it when given an env id)
    """

    metadata = {"render_modes": ["ansi", "rgb_array"], "render_fps": 4}

    @property
    def constraint_spec(self) -> ConstraintSpec:
        """The true constraint: the unsafe cells as states ``row * n_cols + col`` (:mod:`sb3_icrl.common.constraint_spec`)."""
        return ConstraintSpec(unsafe_states=frozenset(np.flatnonzero(self.unsafe_states).tolist()))

    #: Pixels per cell side and the colours of the ``rgb_array`` image
    cell_pixels = 16
    colors = {"free": (255, 255, 255), "unsafe": (220, 50, 50), "goal": (40, 170, 70), "agent": (40, 90, 220)}

    def __init__(
        self,
        map_name: str | None = None,
        desc: Sequence[str] | None = None,
        slip_prob: float = 0.0,
        goal_reward: float = 1.0,
        render_mode: str | None = None,
    ):
        if desc is None:
            map_name = "wall" if map_name is None else map_name
            if map_name not in MAPS:
                raise ValueError(f"Unknown grid map {map_name!r}: choose one of {sorted(MAPS)} or pass `desc=[...]`.")
            desc = MAPS[map_name]
        elif map_name is not None:
            raise ValueError("Give either `map_name` (a named map) or `desc` (your own map), not both.")
        if not 0.0 <= slip_prob <= 1.0:
            raise ValueError(f"`slip_prob` is a probability in [0, 1], got {slip_prob}.")
        if not np.isfinite(goal_reward):
            raise ValueError(f"`goal_reward` must be finite, got {goal_reward}.")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"Unsupported render_mode {render_mode!r}: use None, 'ansi' or 'rgb_array'.")

        self.map_name = map_name
        self.start_cell, self.goal_cell, self.unsafe_mask = parse_map(desc)
        self.desc = tuple(str(row) for row in desc)
        self.n_rows, self.n_cols = self.unsafe_mask.shape
        self.n_states = self.n_rows * self.n_cols
        self.n_actions = len(ACTIONS)
        self.slip_prob = float(slip_prob)
        self.goal_reward = float(goal_reward)
        self.render_mode = render_mode

        self.observation_space = spaces.Discrete(self.n_states)
        self.action_space = spaces.Discrete(self.n_actions)

        self.start_state = self.cell_to_state(*self.start_cell)
        self.goal_state = self.cell_to_state(*self.goal_cell)
        self.unsafe_states = self.unsafe_mask.reshape(-1)
        self.P, self.R, self.C = self._build_tables()
        # Cumulative rows to sample slipping moves with one uniform draw
        self._cumulative_P = np.cumsum(self.P, axis=-1)
        self._state = self.start_state

    def cell_to_state(self, row: int, col: int) -> int:
        """
        :param row: Row of the cell (0 at the top)
        :param col: Column of the cell
        :return: The state index (observation) of the cell
        """
        return int(row) * self.n_cols + int(col)

    def state_to_cell(self, state: int) -> tuple[int, int]:
        """
        :param state: A state index (observation)
        :return: The ``(row, col)`` of the cell
        """
        return divmod(int(state), self.n_cols)

    def _move(self, state: int, action: int) -> int:
        row, col = self.state_to_cell(state)
        new_row, new_col = row + ACTIONS[action, 0], col + ACTIONS[action, 1]
        if 0 <= new_row < self.n_rows and 0 <= new_col < self.n_cols:
            return self.cell_to_state(new_row, new_col)
        return state

    def _build_tables(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n_s, n_a = self.n_states, self.n_actions
        deterministic = np.zeros((n_s, n_a, n_s))
        for state in range(n_s):
            for action in range(n_a):
                deterministic[state, action, self._move(state, action)] = 1.0
        # Slipping: the intended move with prob 1 - p, each of the 8 moves with prob p / 8
        transitions = (1.0 - self.slip_prob) * deterministic + self.slip_prob * deterministic.mean(axis=1, keepdims=True)
        transitions[self.goal_state] = 0.0
        transitions[self.goal_state, :, self.goal_state] = 1.0
        rewards = self.goal_reward * transitions[:, :, self.goal_state]
        costs = transitions @ self.unsafe_states.astype(np.float64)
        rewards[self.goal_state] = 0.0
        costs[self.goal_state] = 0.0
        return transitions, rewards, costs

    def _info(self) -> dict[str, Any]:
        row, col = self.state_to_cell(self._state)
        return {"row": row, "col": col, "cost": float(self.unsafe_states[self._state])}

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[int, dict[str, Any]]:
        super().reset(seed=seed)
        self._state = self.start_state
        return self._state, self._info()

    def step(self, action: int) -> tuple[int, float, bool, bool, dict[str, Any]]:
        action = int(action)
        if not 0 <= action < self.n_actions:
            raise ValueError(f"Invalid action {action}: the grid world has actions 0..{self.n_actions - 1}.")
        if self.slip_prob > 0.0:
            row = self._cumulative_P[self._state, action]
            next_state = min(int(np.searchsorted(row, self.np_random.random() * row[-1], side="right")), self.n_states - 1)
        else:
            next_state = self._move(self._state, action)
        self._state = next_state
        terminated = next_state == self.goal_state
        reward = self.goal_reward if terminated else 0.0
        return next_state, reward, terminated, False, self._info()

    def render(self) -> str | np.ndarray | None:
        if self.render_mode == "rgb_array":
            return self._render_rgb()
        if self.render_mode != "ansi":
            return None
        rows = [list(row) for row in self.desc]
        row, col = self.state_to_cell(self._state)
        rows[row][col] = "A"
        return "\n".join("".join(r) for r in rows) + "\n"

    def _render_rgb(self) -> np.ndarray:
        cells = np.empty((self.n_rows, self.n_cols, 3), dtype=np.uint8)
        cells[:] = self.colors["free"]
        cells[self.unsafe_mask] = self.colors["unsafe"]
        cells[self.goal_cell] = self.colors["goal"]
        cells[self.state_to_cell(self._state)] = self.colors["agent"]
        return np.kron(cells, np.ones((self.cell_pixels, self.cell_pixels, 1), dtype=np.uint8))
