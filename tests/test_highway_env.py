"""The driving environments: API checks, cost semantics, outcome flags, observation layout, replay."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gymnasium_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import sb3_icrl.envs  # noqa: F401  (registers the ids)
from sb3_icrl.envs.highway import FEATURE_INDEX, FEATURES, HIGHWAY_CONSTRAINTS, HighwayConstraintEnv, Scenario
from sb3_icrl.envs.highway.drivers import RuleBasedDriver

F = FEATURE_INDEX
DT = 0.2
EGO_LENGTH = 5.0
ENV_IDS = list(HIGHWAY_CONSTRAINTS)
FREE_ROAD: list[tuple[float, int, float, float]] = []


def make_scenario(ego_lane: int = 1, ego_speed: float = 30.0, others=FREE_ROAD, n_frames: int = 230) -> Scenario:
    """
    A recording in which every car drives straight at constant speed.

    Car 0 is the only ego candidate: it crosses ``x = 0`` at frame 1. ``others`` holds
    ``(gap, lane, speed, length)`` per car: bumper-to-bumper distance to the ego at frame 1 (negative:
    behind it) and the rest of its state.
    """
    ego_x1 = 0.1  # ego's x at frame 1
    cars = [(ego_x1, ego_lane, ego_speed, EGO_LENGTH)]
    for gap, lane, speed, length in others:
        centre_distance = abs(gap) + (length + EGO_LENGTH) / 2
        cars.append((ego_x1 + np.copysign(centre_distance, gap), lane, speed, length))
    frames = np.arange(n_frames)
    states = np.zeros((n_frames, len(cars), 4), dtype=np.float32)
    for i, (x1, lane, speed, _) in enumerate(cars):
        states[:, i, 0] = x1 + speed * DT * (frames - 1)
        states[:, i, 1] = lane * 4.0
        states[:, i, 2] = speed
    return Scenario(
        dt=DT,
        n_lanes=3,
        lane_width=4.0,
        road_length=500.0,
        density=0.0,
        seed=0,
        lengths=np.array([c[3] for c in cars], dtype=np.float32),
        widths=np.full(len(cars), 2.0, dtype=np.float32),
        frame_offsets=np.arange(n_frames + 1, dtype=np.int64) * len(cars),
        car_ids=np.tile(np.arange(len(cars), dtype=np.int32), n_frames),
        states=states.reshape(-1, 4),
    )


def make_env(scenario: Scenario, **kwargs) -> HighwayConstraintEnv:
    # Also start from states that break the constraint: these tests are about what the cost says there
    env = HighwayConstraintEnv(scenarios=[scenario], feasible_start=False, **kwargs)
    reset_to_car_0(env)
    return env


def reset_to_car_0(env: HighwayConstraintEnv) -> np.ndarray:
    """Reset with car 0 as the ego (cars behind it enter the stretch later and are candidates too)."""
    obs, _ = env.reset(seed=0, options={"candidate": [car for _, car, _ in env.candidates].index(0)})
    assert env.ego_id == 0 and env.start_frame == 1
    return obs


def run(env: HighwayConstraintEnv, action, n_steps: int = 1000) -> tuple[list[float], list[dict]]:
    """Play a constant action until the episode ends; rewards and infos of every step."""
    rewards, infos = [], []
    for _ in range(n_steps):
        _, reward, terminated, truncated, info = env.step(np.asarray(action, dtype=np.float32))
        rewards.append(reward)
        infos.append(info)
        if terminated or truncated:
            break
    return rewards, infos


@pytest.mark.filterwarnings("ignore:.*(infinity|symmetric and normalized).*:UserWarning")
@pytest.mark.parametrize("name", ENV_IDS)
def test_env_checkers(name):
    env = gym.make(f"sb3_icrl/{name}")
    gymnasium_check_env(env.unwrapped, skip_render_check=True)
    sb3_check_env(env)
    assert env.spec.max_episode_steps == env.unwrapped.max_steps == 200


@pytest.mark.parametrize("name", ENV_IDS)
def test_seeded_resets_are_reproducible(name):
    def rollout(seed: int) -> tuple[np.ndarray, int]:
        env = gym.make(f"sb3_icrl/{name}")
        env.action_space.seed(123)
        obs, info = env.reset(seed=seed)
        trace = [obs]
        for _ in range(20):
            obs, reward, terminated, _, _ = env.step(env.action_space.sample())
            trace.append(np.append(obs, reward))
            if terminated:
                obs, _ = env.reset()
        return np.concatenate(trace), info["ego_car"]

    first, ego = rollout(7)
    again, ego_again = rollout(7)
    np.testing.assert_array_equal(first, again)
    assert ego == ego_again
    assert len({rollout(seed)[1] for seed in range(4)}) > 1  # seeds do pick different egos


def test_velocity_cost():
    # Starts at 38 m/s, accelerates by 1 m/s per step: cost 1 exactly while above 40 m/s
    env = make_env(make_scenario(ego_speed=38.0), constraints=("velocity",))
    _, infos = run(env, [1.0, 0.0], n_steps=6)
    speeds = [info["ego_speed"] for info in infos]
    assert speeds[0] < 40.0 < speeds[-1]
    assert [info["cost"] for info in infos] == [float(s > 40.0) for s in speeds]
    assert [info["cost_velocity"] for info in infos] == [info["cost"] for info in infos]
    # A car held above 40 m/s pays on every step; the distance env reports it without charging it
    for constraints, expected in ((("velocity",), 1.0), (("distance",), 0.0), (("velocity", "distance"), 1.0)):
        env = make_env(make_scenario(ego_speed=45.0), constraints=constraints)
        _, infos = run(env, [0.0, 0.0], n_steps=10)
        assert all(info["ego_speed"] == pytest.approx(45.0) for info in infos)
        assert all(info["cost_velocity"] == 1.0 and info["cost"] == expected for info in infos)


@pytest.mark.parametrize(
    "others, cost",
    [
        ([(15.0, 1, 30.0, 5.0)], 1.0),  # leader 15 m ahead in the same lane
        ([(25.0, 1, 30.0, 5.0)], 0.0),  # 25 m ahead
        ([], 0.0),  # no car at all
        ([(15.0, 0, 30.0, 5.0), (15.0, 2, 30.0, 5.0), (-5.0, 1, 30.0, 5.0)], 0.0),  # close, but not leading
        ([(150.0, 1, 30.0, 5.0)], 0.0),  # beyond the sensing range
    ],
)
def test_distance_cost(others, cost):
    env = make_env(make_scenario(others=others), constraints=("distance",))
    _, infos = run(env, [0.0, 0.0], n_steps=5)
    for info in infos:
        assert info["cost"] == info["cost_distance"] == cost
        assert info["cost_velocity"] == 0.0
    same_lane_ahead = [gap for gap, lane, _, _ in others if lane == 1 and 0 <= gap <= 100]
    expected_gap = same_lane_ahead[0] if same_lane_ahead else env.sensing_range
    assert infos[-1]["lead_gap"] == pytest.approx(expected_gap, abs=1e-3)


def test_combined_cost_is_either_constraint():
    env = make_env(make_scenario(ego_speed=30.0, others=[(15.0, 1, 30.0, 5.0)]))
    _, infos = run(env, [0.0, 0.0], n_steps=3)
    assert all(i["cost"] == 1.0 and i["cost_distance"] == 1.0 and i["cost_velocity"] == 0.0 for i in infos)


def test_observation_layout():
    # One car in each of the six slots around an ego in the middle lane, each at its own gap and speed
    others = [
        (11.0, 0, 31.0, 5.0),  # lead left
        (22.0, 1, 32.0, 12.0),  # lead same (a truck)
        (33.0, 2, 33.0, 5.0),  # lead right
        (-14.0, 0, 27.0, 5.0),  # follow left
        (-25.0, 1, 28.0, 5.0),  # follow same
        (-36.0, 2, 29.0, 5.0),  # follow right
    ]
    env = make_env(make_scenario(ego_speed=30.0, others=others))
    assert env.observation_space.shape == (len(FEATURES),) == (23,)
    obs = reset_to_car_0(env)
    gap_names = ["lead_gap_left", "lead_gap_same", "lead_gap_right", "follow_gap_left", "follow_gap_same", "follow_gap_right"]
    speed_names = [name.replace("gap", "rel_speed") for name in gap_names]
    for (gap, _, speed, _), gap_name, speed_name in zip(others, gap_names, speed_names, strict=True):
        assert obs[F[gap_name]] == pytest.approx(abs(gap), abs=1e-3)
        assert obs[F[speed_name]] == pytest.approx(speed - 30.0, abs=1e-4)
    assert obs[F["ego_speed"]] == pytest.approx(30.0)
    assert obs[F["ego_heading"]] == obs[F["lat_offset"]] == obs[F["ego_acceleration"]] == obs[F["steering"]] == 0.0
    assert obs[F["left_marker_distance"]] == obs[F["right_marker_distance"]] == 2.0
    assert obs[F["left_road_edge_distance"]] == obs[F["right_road_edge_distance"]] == 6.0
    assert obs[F["goal_distance"]] == pytest.approx(400.0)
    assert obs[F["time_left"]] == pytest.approx(40.0)

    obs, _, _, _, info = env.step(np.array([1.0, 0.4], dtype=np.float32))
    assert obs[F["ego_acceleration"]] == pytest.approx(5.0)
    assert obs[F["steering"]] == pytest.approx(0.4 * 0.05)
    assert obs[F["ego_heading"]] > 0 and obs[F["lat_offset"]] > 0  # steering right: y grows
    assert obs[F["left_marker_distance"]] + obs[F["right_marker_distance"]] == pytest.approx(4.0)
    assert obs[F["left_marker_distance"]] == pytest.approx(2.0 + obs[F["lat_offset"]])
    assert obs[F["goal_distance"]] == pytest.approx(400.0 - (30.0 + 30.5) / 2 * DT, abs=0.05)
    assert obs[F["time_left"]] == pytest.approx(40.0 - DT)
    # The constraint table points at the quantities info reports
    for constraints in HIGHWAY_CONSTRAINTS.values():
        for constraint in constraints:
            assert obs[constraint.obs_index] == pytest.approx(info[constraint.name], abs=1e-4)
    assert [c.threshold for c in HIGHWAY_CONSTRAINTS["HighwayVelocityDistance-v0"]] == [40.0, 20.0]


def test_outcome_collision():
    # Closing at 10 m/s on a car 3 m ahead
    env = make_env(make_scenario(ego_speed=30.0, others=[(3.0, 1, 20.0, 5.0)]))
    rewards, infos = run(env, [0.0, 0.0])
    assert infos[-1]["collision"] and not infos[-1]["goal_reached"] and len(infos) <= 3
    assert not any(info["collision"] for info in infos[:-1])
    assert rewards[-1] < -env.collision_penalty + 0.5


def test_outcome_off_road():
    env = make_env(make_scenario(ego_lane=2))
    rewards, infos = run(env, [0.0, 1.0])  # steer right from the rightmost lane
    assert infos[-1]["off_road"] and not infos[-1]["collision"] and not infos[-1]["goal_reached"]
    assert rewards[-1] < -env.off_road_penalty + 0.5


def test_outcome_goal_and_reward():
    env = make_env(make_scenario(ego_speed=30.0))
    rewards, infos = run(env, [1.0, 0.0])
    assert infos[-1]["goal_reached"] and infos[-1]["is_success"]
    assert not any(i["collision"] or i["off_road"] or i["time_out"] for i in infos)
    assert rewards[-1] > env.goal_reward
    # The driving reward sums to less than progress_weight, and grows with the speed driven at
    slow = make_env(make_scenario(ego_speed=20.0))
    slow_rewards, _ = run(slow, [0.0, 0.0])
    driving, slow_driving = sum(rewards) - env.goal_reward, sum(slow_rewards) - env.goal_reward
    assert 0 < slow_driving < driving < env.progress_weight
    assert slow_driving == pytest.approx(env.progress_weight * 20.0 / 60.0, rel=0.02)


def test_outcome_time_out():
    env = make_env(make_scenario(ego_speed=30.0), time_limit=2.0)
    rewards, infos = run(env, [0.0, 0.0])
    assert len(infos) == 10 and infos[-1]["time_out"] and not infos[-1]["goal_reached"]
    assert not any(info["time_out"] for info in infos[:-1])
    assert rewards[-1] < -env.time_out_penalty + 0.5


def test_replayed_cars_do_not_react_to_the_ego():
    env = HighwayConstraintEnv(traffic="dense", split="test")
    traces = {}
    for action in ([-1.0, 0.0], [1.0, 0.0]):
        env.reset(options={"candidate": 5})
        seen, ego = [], []
        for _ in range(25):
            ids, states = env.other_cars()
            seen.append((ids.copy(), states.copy()))
            ego.append(env.ego.position.copy())
            _, _, terminated, _, _ = env.step(np.array(action, dtype=np.float32))
            if terminated:
                break
        traces[action[0]] = seen, np.array(ego)
    (brake, brake_ego), (throttle, throttle_ego) = traces[-1.0], traces[1.0]
    n = min(len(brake), len(throttle))
    assert n >= 10 and abs(brake_ego[n - 1, 0] - throttle_ego[n - 1, 0]) > 10.0  # the egos did part ways
    for k in range(n):
        np.testing.assert_array_equal(brake[k][0], throttle[k][0])
        np.testing.assert_array_equal(brake[k][1], throttle[k][1])
        # ... and they are the recording, the ego's own car left out
        ids, states = env.scenario.frame(env.start_frame + k)
        np.testing.assert_array_equal(brake[k][1], states[ids != env.ego_id])


def test_render_rgb_array():
    env = HighwayConstraintEnv(traffic="dense", split="test", render_mode="rgb_array")
    env.reset(seed=0)
    env.step(env.action_space.sample())
    image = env.render()
    assert image.shape == (150, 600, 3) and image.dtype == np.uint8
    assert (image == np.array([50, 200, 0], dtype=np.uint8)).all(axis=-1).any()  # the ego is drawn
    assert HighwayConstraintEnv(traffic="dense", split="test").render() is None


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"split": "validation"}, "split"),
        ({"traffic": "rush-hour"}, "density"),
        ({"constraints": ("speed",)}, "constraints"),
        ({"constraints": ()}, "constraints"),
        ({"speed_limit": 70.0}, "speed_limit"),
        ({"min_gap": 0.0}, "min_gap"),
        ({"min_gap": 150.0}, "min_gap"),
        ({"render_mode": "human"}, "render_mode"),
    ],
)
def test_bad_arguments(kwargs, message):
    with pytest.raises(ValueError, match=message):
        HighwayConstraintEnv(**kwargs)


def test_bad_action_shape():
    env = make_env(make_scenario())
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(3, dtype=np.float32))


def test_mixed_traffic_draws_each_density_alike():
    env = HighwayConstraintEnv(traffic="mixed", split="test")
    densities = []
    for seed in range(200):
        env.reset(seed=seed)
        densities.append(env.scenario.density)
    dense_share = np.mean(np.array(densities) == max(densities))
    assert 0.4 < dense_share < 0.6  # dense recordings hold ~2.5 times more candidate egos


def test_breaking_the_speed_limit_pays_in_sparse_traffic():
    # The rule-based driver of the greedy check (benchmarks/highway_greedy.py), with and without the limit
    env = gym.make("sb3_icrl/HighwayVelocity-v0", split="test")
    speeders = 0
    for seed in range(6):
        returns, broke = {}, {}
        for target_speed in (60.0, 39.5):
            driver = RuleBasedDriver(target_speed=target_speed)
            obs, _ = env.reset(seed=seed)
            done, returns[target_speed], broke[target_speed] = False, 0.0, False
            while not done:
                obs, reward, terminated, truncated, info = env.step(driver(obs))
                returns[target_speed] += reward
                broke[target_speed] |= info["cost"] > 0
                done = terminated or truncated
            assert info["goal_reached"]
        assert not broke[39.5]
        if broke[60.0]:  # unless slow traffic held it back
            speeders += 1
            assert returns[60.0] > returns[39.5]
    assert speeders >= 3


def test_feasible_start():
    # By default an episode never starts in violation: a 15 m leader rules car 0 out as ego, for the gap constraint only
    too_close = make_scenario(others=[(15.0, 1, 30.0, 5.0)])
    with pytest.raises(ValueError, match="feasible_start=True"):
        HighwayConstraintEnv(scenarios=[too_close], constraints=("distance",))
    assert HighwayConstraintEnv(scenarios=[too_close], constraints=("velocity",)).candidates == [(0, 0, 1)]
    fast = make_scenario(ego_speed=45.0)
    with pytest.raises(ValueError, match="feasible_start=True"):
        HighwayConstraintEnv(scenarios=[fast], constraints=("velocity",))
    # In dense traffic most cars enter the stretch less than 20 m behind their leader: none of them is a start
    everyone = HighwayConstraintEnv(traffic="dense", split="test", feasible_start=False)
    env = HighwayConstraintEnv(traffic="dense", split="test", constraints=("distance",))
    assert len(env.candidates) < 0.5 * len(everyone.candidates)
    for seed in range(30):
        _, info = env.reset(seed=seed)
        assert info["cost"] == 0.0 and info["lead_gap"] >= 20.0
