"""The grid world: API checks, maps, dynamics tables against the simulator, costs and input errors."""

from collections import deque

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gymnasium_check_env
from stable_baselines3 import PPO
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import sb3_icrl.envs  # noqa: F401
from sb3_icrl.envs import MAPS
from sb3_icrl.envs.grid_world import ACTION_NAMES, ACTIONS, GridWorldEnv

GRID_IDS = ["GridWorld-v0", "GridWorldWall-v0", "GridWorldSquare-v0", "GridWorldBigSquare-v0", "GridWorldZigzag-v0"]
UNSAFE_COUNTS = {"wall": 5, "square": 9, "big-square": 25, "zigzag": 10}
RIGHT, LEFT, DOWN, UP = (ACTION_NAMES.index(name) for name in ("right", "left", "down", "up"))


def shortest_path_length(env: GridWorldEnv, avoid_unsafe: bool) -> int:
    """Breadth-first search over king moves from start to goal."""
    start, goal = env.start_state, env.goal_state
    distances = {start: 0}
    queue = deque([start])
    while queue:
        state = queue.popleft()
        for action in range(env.n_actions):
            nxt = int(np.argmax(env.P[state, action]))
            if nxt in distances or (avoid_unsafe and env.unsafe_states[nxt]):
                continue
            distances[nxt] = distances[state] + 1
            queue.append(nxt)
    return distances[goal]


@pytest.mark.parametrize("name", GRID_IDS)
@pytest.mark.parametrize("slip_prob", [0.0, 0.2])
def test_env_checkers(name, slip_prob):
    env = gym.make(f"sb3_icrl/{name}", slip_prob=slip_prob)
    gymnasium_check_env(env.unwrapped)
    sb3_check_env(env)
    assert env.spec.max_episode_steps == 50
    assert env.observation_space == gym.spaces.Discrete(49) and env.action_space == gym.spaces.Discrete(8)


@pytest.mark.parametrize("map_name", list(MAPS))
def test_maps_shape_sizes_and_detour(map_name):
    env = GridWorldEnv(map_name=map_name)
    assert (env.n_rows, env.n_cols) == (7, 7)
    assert env.start_cell == (0, 0)
    assert int(env.unsafe_mask.sum()) == UNSAFE_COUNTS[map_name]
    assert not env.unsafe_mask[env.start_cell] and not env.unsafe_mask[env.goal_cell]
    # Every map forces a detour: the shortest safe path is longer than the shortest path
    assert shortest_path_length(env, avoid_unsafe=True) > shortest_path_length(env, avoid_unsafe=False)


def test_default_and_registered_maps():
    assert gym.make("sb3_icrl/GridWorld-v0").unwrapped.map_name == "wall"
    assert gym.make("sb3_icrl/GridWorldZigzag-v0").unwrapped.desc == MAPS["zigzag"]
    assert gym.make("sb3_icrl/GridWorld-v0", map_name="big-square").unwrapped.goal_cell == (6, 6)
    assert GridWorldEnv("wall").goal_cell == (6, 0)


@pytest.mark.parametrize("slip_prob", [0.0, 0.3])
def test_tables_are_consistent(slip_prob):
    env = GridWorldEnv(map_name="square", slip_prob=slip_prob)
    np.testing.assert_allclose(env.P.sum(axis=-1), 1.0)
    goal = env.goal_state
    np.testing.assert_array_equal(env.P[goal, :, goal], 1.0)
    assert np.all(env.R[goal] == 0) and np.all(env.C[goal] == 0)
    others = np.arange(env.n_states) != goal
    np.testing.assert_allclose(env.R[others], env.P[others][:, :, goal])
    np.testing.assert_allclose(env.C[others], env.P[others] @ env.unsafe_states)
    if slip_prob == 0.0:
        assert set(np.unique(env.P)) == {0.0, 1.0}


def test_deterministic_moves_costs_and_goal():
    env = gym.make("sb3_icrl/GridWorldWall-v0")
    obs, info = env.reset(seed=0)
    assert obs == 0 and info["cost"] == 0.0
    # Off the grid: stay in place
    obs, reward, terminated, _, info = env.step(UP)
    assert obs == 0 and (info["row"], info["col"]) == (0, 0) and reward == 0.0 and not terminated
    costs = []
    for _ in range(6):  # straight down column 0, through the wall at row 3
        obs, reward, terminated, _, info = env.step(DOWN)
        costs.append(info["cost"])
        assert env.unwrapped.state_to_cell(obs) == (info["row"], info["col"])
    assert costs == [0.0, 0.0, 1.0, 0.0, 0.0, 0.0]
    assert (info["row"], info["col"]) == (6, 0) and reward == 1.0 and terminated


@pytest.mark.parametrize("state, action", [(0, 4), (24, 7), (10, 2)])
def test_slipping_matches_transition_table(state, action):
    env = GridWorldEnv(map_name="zigzag", slip_prob=0.4)
    env.reset(seed=1)
    n_samples = 4000
    counts = np.zeros(env.n_states)
    for _ in range(n_samples):
        env._state = state
        counts[env.step(action)[0]] += 1
    np.testing.assert_allclose(counts / n_samples, env.P[state, action], atol=0.03)


def test_seeded_slipping_is_reproducible():
    def rollout(seed: int) -> list[int]:
        env = gym.make("sb3_icrl/GridWorld-v0", slip_prob=0.5)
        env.reset(seed=seed)
        return [int(env.step(RIGHT)[0]) for _ in range(30)]

    assert rollout(3) == rollout(3)
    assert rollout(3) != rollout(4)


def test_time_limit_truncates_at_50_steps():
    env = gym.make("sb3_icrl/GridWorld-v0")
    env.reset(seed=0)
    for step in range(1, 51):
        _, _, terminated, truncated, _ = env.step(LEFT)
        assert not terminated and truncated == (step == 50)


def test_user_map_and_render():
    env = GridWorldEnv(desc=["S.X.", "..XG"], render_mode="ansi")
    assert (env.n_rows, env.n_cols) == (2, 4) and env.goal_cell == (1, 3)
    assert env.observation_space.n == 8 and int(env.unsafe_mask.sum()) == 2
    env.reset(seed=0)
    _, _, _, _, info = env.step(ACTIONS.tolist().index([1, 1]))  # down-right into (1, 1)
    assert (info["row"], info["col"]) == (1, 1) and info["cost"] == 0.0
    _, _, _, _, info = env.step(RIGHT)
    assert info["cost"] == 1.0
    assert env.render() == "S.X.\n..AG\n"


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"map_name": "maze"}, "Unknown grid map 'maze'"),
        ({"desc": ["S..", "..G."]}, "same, non-zero length"),
        ({"desc": ["S..", "..."]}, "exactly one 'G'"),
        ({"desc": ["SS.", "..G"]}, "exactly one 'S'"),
        ({"desc": ["S.#", "..G"]}, "Unknown map characters"),
        ({"desc": "S.G"}, "list of strings"),
        ({"map_name": "wall", "desc": ["S.G"]}, "not both"),
        ({"slip_prob": 1.5}, "slip_prob"),
        ({"render_mode": "human"}, "render_mode"),
    ],
)
def test_bad_arguments(kwargs, message):
    with pytest.raises(ValueError, match=message):
        GridWorldEnv(**kwargs)


def test_invalid_action():
    env = GridWorldEnv()
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"actions 0\.\.7"):
        env.step(8)


def test_rgb_array_render_and_env_id_with_sb3():
    env = GridWorldEnv(map_name="wall", render_mode="rgb_array")
    env.reset(seed=0)
    image = env.render()
    size = GridWorldEnv.cell_pixels
    assert image.shape == (7 * size, 7 * size, 3) and image.dtype == np.uint8
    assert tuple(image[0, 0]) == GridWorldEnv.colors["agent"]  # the agent starts top-left
    assert tuple(image[3 * size, 0]) == GridWorldEnv.colors["unsafe"]  # the wall starts at row 3
    assert tuple(image[6 * size, 0]) == GridWorldEnv.colors["goal"]
    assert tuple(image[0, size]) == GridWorldEnv.colors["free"]
    # SB3 builds envs given by id with render_mode="rgb_array"
    PPO("MlpPolicy", "sb3_icrl/GridWorldWall-v0", n_steps=8, batch_size=8).learn(8)
