"""
Highway driving environments of the ICRL benchmark (the paper's "HighD" environments, rebuilt on highway-env).

An ego car drives along a straight three-lane highway, from where it enters the recorded stretch
(``x = 0``) to a goal line ``goal_distance`` metres on (400 m by default, about the length of HighD's
stretches), among recorded traffic that is replayed without reacting to it (see
:mod:`sb3_icrl.envs.highway.scenarios`). The ego moves with highway-env's kinematic bicycle model
(``highway_env.vehicle.kinematics.Vehicle``), its speed range widened to ``speed_range`` (``[0, 60]``
m/s) so that the 40 m/s limit can be broken.

Action: ``[acceleration, steering]`` in ``[-1, 1]^2``, mapped linearly to ``acceleration_range``
(``[-5, 5]`` m/s^2) and ``steering_range`` (``[-0.05, 0.05]`` rad: with highway-env's ``pi / 4`` a random
policy leaves the road within a few steps). One step is ``dt = 0.2`` s (two integration sub-steps).

Observation (float32, 23 features modelled on CommonRoad-RL's, which the paper uses; gaps are bumper
to bumper, "left" is the lane with the lower index, i.e. smaller ``y``; ``+`` lateral values point right):

====  ============================  ==========================================================================
idx   name                          meaning
====  ============================  ==========================================================================
0     ``ego_speed``                 ego speed [m/s] (the velocity constraint is on it)
1     ``ego_acceleration``          acceleration realised over the last step [m/s^2]
2     ``ego_heading``               heading relative to the road [rad]
3     ``steering``                  steering angle applied over the last step [rad]
4     ``lat_offset``                lateral offset from the centre of the ego's lane [m]
5     ``left_marker_distance``      distance from the ego's centre to its lane's left marking [m]
6     ``right_marker_distance``     distance to its lane's right marking [m]
7     ``left_road_edge_distance``   distance to the left road edge [m]
8     ``right_road_edge_distance``  distance to the right road edge [m]
9     ``lead_gap_left``             gap to the nearest car ahead in the left lane [m]
10    ``lead_gap_same``             gap to the car ahead in the ego's lane [m] (the distance constraint is on it)
11    ``lead_gap_right``            gap to the nearest car ahead in the right lane [m]
12    ``follow_gap_left``           gap to the nearest car behind in the left lane [m]
13    ``follow_gap_same``           gap to the car behind in the ego's lane [m]
14    ``follow_gap_right``          gap to the nearest car behind in the right lane [m]
15    ``lead_rel_speed_left``       speed of that car minus the ego's [m/s] (likewise 16-20)
16    ``lead_rel_speed_same``
17    ``lead_rel_speed_right``
18    ``follow_rel_speed_left``
19    ``follow_rel_speed_same``
20    ``follow_rel_speed_right``
21    ``goal_distance``             longitudinal distance to the goal line [m]
22    ``time_left``                 time before the time-out [s]
====  ============================  ==========================================================================

A car counts as in a lane when its centre is nearest to that lane's centre, and is seen when its centre
is within ``sensing_range`` (100 m) of the ego's. Without such a car (or without such a lane) the gap
is ``sensing_range`` and the relative speed 0, as in CommonRoad-RL.

Reward, per step: ``progress_weight * (v / v_max) * dx / goal_distance`` (progress weighted by speed:
summed over an episode it is at most ``progress_weight``, reached only at the top speed ``v_max`` all
the way, so the speed reward keeps rising up to ``v_max = speed_range[1]``), plus ``goal_reward`` on
reaching the goal, minus ``collision_penalty``, ``off_road_penalty`` or ``time_out_penalty``. Every one
of those four outcomes ends the episode (``terminated``: the time left is observed), as in the
paper's CommonRoad-RL environment.

``info`` of every step (and of ``reset``): ``cost`` (1.0 when one of this env's constraints is broken
in the state reached, else 0.0), ``cost_velocity`` and ``cost_distance`` (each constraint alone,
whether the env uses it or not), ``constraint_costs`` (``{name: cost}`` of this env's own constraints, for
the per-constraint violation rates of evaluations), ``ego_speed``, ``lead_gap`` and the outcome flags ``collision``,
``off_road``, ``time_out``, ``goal_reached`` (also as ``is_success``). The learner must not read the costs.
``reset`` adds ``scenario``, ``ego_car`` and ``start_frame``: which recorded car the ego replaces, and when.

Registered ids: ``HighwayVelocity-v0`` (speed constraint, sparse traffic), ``HighwayDistance-v0`` (gap
constraint, dense traffic) and ``HighwayVelocityDistance-v0`` (both, recordings of both densities drawn
alike): in sparse traffic breaking the speed limit pays, in dense traffic short gaps do (see
``benchmarks/highway_greedy.py``). Their registered step limit is 200 (40 s); pass
``max_episode_steps`` along with a longer ``time_limit``.

Differences from the paper's HighD environments: highway-env kinematics instead of CommonRoad's;
simulated recordings instead of HighD (see :mod:`sb3_icrl.envs.highway.scenarios`); 23 features
instead of 76 (no lane curvature, route or friction features: the road is straight); 5 Hz instead of
25 Hz; one 400 m route per ego. By default (``feasible_start=True``) the ego only takes over recorded
cars that satisfy the env's constraints at the take-over; the paper does not filter
(``feasible_start=False``), and then 70 % of the dense starts break the gap constraint before the
agent has acted. Recorded cars never exceed 40 m/s.

:data:`HIGHWAY_CONSTRAINTS` gives, per environment id, the observation index and threshold of each
true constraint (default thresholds); each env declares its own, with its thresholds, as the property
``constraint_spec`` (:mod:`sb3_icrl.common.constraint_spec`). Thresholds are constructor arguments
(``gymnasium.make("sb3_icrl/HighwayDistance-v0", min_gap=25.0)``).
"""

from collections.abc import Sequence
from functools import lru_cache
from typing import Any, ClassVar, NamedTuple

import gymnasium
import numpy as np
from gymnasium import spaces
from highway_env import utils
from highway_env.road.road import Road, RoadNetwork
from highway_env.vehicle.kinematics import Vehicle
from numpy.typing import NDArray

from sb3_icrl.common.constraint_spec import ConstraintSpec, FeatureConstraint
from sb3_icrl.envs.highway.scenarios import STORE_MARGIN, Scenario, scenario_files

#: Names of the observation features, in order (see the module docstring)
FEATURES: tuple[str, ...] = (
    "ego_speed",
    "ego_acceleration",
    "ego_heading",
    "steering",
    "lat_offset",
    "left_marker_distance",
    "right_marker_distance",
    "left_road_edge_distance",
    "right_road_edge_distance",
    "lead_gap_left",
    "lead_gap_same",
    "lead_gap_right",
    "follow_gap_left",
    "follow_gap_same",
    "follow_gap_right",
    "lead_rel_speed_left",
    "lead_rel_speed_same",
    "lead_rel_speed_right",
    "follow_rel_speed_left",
    "follow_rel_speed_same",
    "follow_rel_speed_right",
    "goal_distance",
    "time_left",
)
FEATURE_INDEX: dict[str, int] = {name: i for i, name in enumerate(FEATURES)}


class DrivingConstraint(NamedTuple):
    """
    A true constraint of the driving environments.

    :param name: Key of the constrained quantity in ``info`` (``"ego_speed"`` or ``"lead_gap"``)
    :param obs_index: Index of the quantity in the observation
    :param threshold: Default threshold (a constructor argument of the environment)
    :param op: ``">"``: broken when ``value > threshold``; ``"<"``: broken when ``value < threshold``
    """

    name: str
    obs_index: int
    threshold: float
    op: str


#: The two constraints of the paper: ego speed <= 40 m/s, gap to the leading car >= 20 m
DRIVING_CONSTRAINTS: dict[str, DrivingConstraint] = {
    "velocity": DrivingConstraint("ego_speed", FEATURE_INDEX["ego_speed"], 40.0, ">"),
    "distance": DrivingConstraint("lead_gap", FEATURE_INDEX["lead_gap_same"], 20.0, "<"),
}

#: True constraints of each driving environment id (default thresholds)
HIGHWAY_CONSTRAINTS: dict[str, tuple[DrivingConstraint, ...]] = {
    "HighwayVelocity-v0": (DRIVING_CONSTRAINTS["velocity"],),
    "HighwayDistance-v0": (DRIVING_CONSTRAINTS["distance"],),
    "HighwayVelocityDistance-v0": (DRIVING_CONSTRAINTS["velocity"], DRIVING_CONSTRAINTS["distance"]),
}


@lru_cache(maxsize=64)
def _load(path: str) -> Scenario:
    # Shared by every env of the process (vectorised envs): the arrays are only read
    return Scenario.load(path)


def _polygon(x: float, y: float, heading: float, length: float, width: float) -> NDArray[np.float64]:
    """Closed corner list of a rectangle, as highway-env's ``RoadObject.polygon``."""
    c, s = np.cos(heading), np.sin(heading)
    corners = np.array([[-length, -width], [-length, width], [length, width], [length, -width]]) / 2
    points = corners @ np.array([[c, s], [-s, c]]) + np.array([x, y])
    return np.vstack([points, points[:1]])


class HighwayConstraintEnv(gymnasium.Env):
    """
    Drive to the goal among replayed traffic, under a speed and/or gap constraint.

    :param constraints: Names of the true constraints: ``"velocity"`` and/or ``"distance"``
    :param traffic: ``"sparse"``, ``"dense"`` or ``"mixed"`` (both): which recordings to replay
    :param split: ``"train"`` or ``"test"`` recordings
    :param speed_limit: Velocity constraint: cost 1 when the ego speed is above it [m/s]
    :param min_gap: Distance constraint: cost 1 when the gap to the leading car is below it [m]
    :param goal_distance: Distance from the entry (``x = 0``) to the goal line [m]
    :param time_limit: Episode time limit [s]
    :param sensing_range: How far the ego sees other cars [m]
    :param speed_range: Speeds the ego can reach [m/s]; its top is the top of the speed reward
    :param acceleration_range: Accelerations the first action component maps to [m/s^2]
    :param steering_range: Steering angles the second action component maps to [rad]
    :param progress_weight: Reward for covering the route at top speed (see the module docstring)
    :param goal_reward: Bonus on reaching the goal
    :param collision_penalty: Penalty on a collision
    :param off_road_penalty: Penalty on leaving the road
    :param time_out_penalty: Penalty on running out of time
    :param scenarios: Recordings to replay instead of the shipped ones (``traffic`` and ``split`` are then ignored)
    :param feasible_start: Only take over recorded cars that satisfy this env's constraints at the take-over
        (in dense traffic 70 % of the cars enter the stretch less than 20 m behind their leader: such starts
        would be violations no policy can avoid, which the paper found makes a threshold useless)
    :param render_mode: ``None`` or ``"rgb_array"``
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 5}
    #: What a held-out evaluation changes (:func:`sb3_icrl.envs.heldout_env_kwargs`): the recordings no run trained on
    heldout_env_kwargs: ClassVar[dict[str, Any]] = {"split": "test"}

    @property
    def constraint_spec(self) -> ConstraintSpec:
        """This env's true constraints with its thresholds (see :mod:`sb3_icrl.common.constraint_spec`)."""
        thresholds = {"velocity": self.speed_limit, "distance": self.min_gap}
        return ConstraintSpec(
            features=tuple(
                FeatureConstraint(
                    DRIVING_CONSTRAINTS[c].obs_index, thresholds[c], DRIVING_CONSTRAINTS[c].op, DRIVING_CONSTRAINTS[c].name
                )
                for c in self.constraints
            )
        )

    def __init__(
        self,
        constraints: Sequence[str] = ("velocity", "distance"),
        traffic: str = "mixed",
        split: str = "train",
        speed_limit: float = 40.0,
        min_gap: float = 20.0,
        goal_distance: float = 400.0,
        time_limit: float = 40.0,
        sensing_range: float = 100.0,
        speed_range: tuple[float, float] = (0.0, 60.0),
        acceleration_range: tuple[float, float] = (-5.0, 5.0),
        steering_range: tuple[float, float] = (-0.05, 0.05),
        progress_weight: float = 20.0,
        goal_reward: float = 5.0,
        collision_penalty: float = 10.0,
        off_road_penalty: float = 10.0,
        time_out_penalty: float = 5.0,
        scenarios: Sequence[Scenario] | None = None,
        feasible_start: bool = True,
        render_mode: str | None = None,
    ) -> None:
        super().__init__()
        constraints = tuple(constraints)
        unknown = set(constraints) - set(DRIVING_CONSTRAINTS)
        if unknown or not constraints:
            raise ValueError(f"constraints must be a non-empty subset of {tuple(DRIVING_CONSTRAINTS)}, got {constraints}")
        if not speed_range[0] < speed_limit < speed_range[1]:
            raise ValueError(f"speed_limit must lie inside speed_range {speed_range} to be breakable, got {speed_limit}")
        if not 0.0 < min_gap < sensing_range:
            raise ValueError(f"min_gap must be in (0, sensing_range={sensing_range}) m, got {min_gap}")
        if goal_distance <= 0 or time_limit <= 0:
            raise ValueError(f"goal_distance and time_limit must be > 0, got {goal_distance} and {time_limit}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.constraints = constraints
        self.speed_limit, self.min_gap = float(speed_limit), float(min_gap)
        self.goal_distance, self.time_limit, self.sensing_range = float(goal_distance), float(time_limit), float(sensing_range)
        self.speed_range, self.acceleration_range, self.steering_range = speed_range, acceleration_range, steering_range
        self.progress_weight, self.goal_reward = progress_weight, goal_reward
        self.collision_penalty, self.off_road_penalty, self.time_out_penalty = (
            collision_penalty,
            off_road_penalty,
            time_out_penalty,
        )
        self.render_mode = render_mode

        self.scenarios = list(scenarios) if scenarios is not None else [_load(p) for p in scenario_files(traffic, split)]
        first = self.scenarios[0]
        self.dt, self.n_lanes, self.lane_width = first.dt, first.n_lanes, first.lane_width
        if any((s.dt, s.n_lanes, s.lane_width) != (self.dt, self.n_lanes, self.lane_width) for s in self.scenarios):
            raise ValueError("All scenarios must share dt, n_lanes and lane_width")
        if any(goal_distance + sensing_range > s.road_length + STORE_MARGIN for s in self.scenarios):
            raise ValueError("goal_distance + sensing_range goes past the end of a recorded stretch")
        self.max_steps = round(time_limit / self.dt)
        self.substeps = 2
        # (scenario index, car id, start frame) of every car that can be the ego
        self.candidates = [
            (i, int(car), int(frame)) for i, s in enumerate(self.scenarios) for car, frame in s.ego_candidates(self.max_steps)
        ]
        if feasible_start:
            self.candidates = [c for c in self.candidates if self._start_is_feasible(*c)]
        if not self.candidates:
            raise ValueError(
                f"No car of the scenarios can be the ego for {self.max_steps} steps (feasible_start={feasible_start})"
            )
        # Resets draw a recording first, so that dense recordings (more cars) do not outweigh sparse ones
        per_scenario = np.bincount([i for i, _, _ in self.candidates], minlength=len(self.scenarios))
        self._candidate_starts = np.concatenate([[0], np.cumsum(per_scenario)])
        self._drawable = np.flatnonzero(per_scenario)

        self.action_space = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(len(FEATURES),), dtype=np.float32)

        road_length = max(s.road_length for s in self.scenarios) + 2 * STORE_MARGIN
        network = RoadNetwork.straight_road_network(
            lanes=self.n_lanes, start=-STORE_MARGIN, length=road_length, speed_limit=speed_range[1]
        )
        self.road = Road(network=network, np_random=self.np_random, record_history=False)
        self.left_edge = -self.lane_width / 2
        self.right_edge = (self.n_lanes - 0.5) * self.lane_width
        self.ego: Vehicle | None = None
        self._surface: Any = None

    def _start_is_feasible(self, scenario: int, car: int, frame: int) -> bool:
        """Whether the recorded car satisfies this env's constraints where the ego would take it over."""
        recording = self.scenarios[scenario]
        if "velocity" in self.constraints:
            ids, states = recording.frame(frame)
            if states[np.flatnonzero(ids == car)[0], 2] > self.speed_limit:
                return False
        return "distance" not in self.constraints or recording.lead_gap(car, frame) >= self.min_gap

    # ------------------------------------------------------------------ episode

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[NDArray[np.float32], dict]:
        """
        :param seed: Seed of the choice of recording (uniform) and of the ego car in it (uniform)
        :param options: ``{"candidate": i}`` picks ``self.candidates[i]`` instead of a random one
        :return: First observation and info
        """
        super().reset(seed=seed)
        options = options or {}
        if "candidate" in options:
            index = int(options["candidate"])
        else:
            scenario = self._drawable[self.np_random.integers(len(self._drawable))]
            index = int(self.np_random.integers(self._candidate_starts[scenario], self._candidate_starts[scenario + 1]))
        self.scenario_index, self.ego_id, self.start_frame = self.candidates[index]
        self.scenario = self.scenarios[self.scenario_index]
        ids, states = self.scenario.frame(self.start_frame)
        x, y, speed, heading = (float(v) for v in states[np.flatnonzero(ids == self.ego_id)[0]])
        self.ego = Vehicle(self.road, [x, y], heading, speed)
        self.ego.MIN_SPEED, self.ego.MAX_SPEED = self.speed_range
        self.ego.LENGTH = float(self.scenario.lengths[self.ego_id])
        self.ego.WIDTH = float(self.scenario.widths[self.ego_id])
        self.ego.color = (50, 200, 0)
        self.start_x = x
        self.steps = 0
        self.acceleration = self.steering = 0.0
        obs, info = self._observe()
        info.update(scenario=self.scenario_index, ego_car=self.ego_id, start_frame=self.start_frame)
        return obs, info

    def step(self, action: NDArray) -> tuple[NDArray[np.float32], float, bool, bool, dict]:
        """
        :param action: ``[acceleration, steering]`` in ``[-1, 1]``
        :return: observation, reward, terminated, truncated (always False: the env ends itself), info
        """
        if self.ego is None:
            raise RuntimeError("Call reset() before step()")
        action = np.clip(np.asarray(action, dtype=np.float64).reshape(-1), -1.0, 1.0)
        if action.shape != (2,):
            raise ValueError(f"Expected an action of shape (2,), got {np.shape(action)}")
        acceleration = utils.lmap(action[0], [-1, 1], self.acceleration_range)
        self.steering = utils.lmap(action[1], [-1, 1], self.steering_range)
        x_before, speed_before = self.ego.position[0], self.ego.speed
        self.ego.act({"acceleration": acceleration, "steering": self.steering})
        for _ in range(self.substeps):
            self.ego.step(self.dt / self.substeps)
            # highway-env lets the speed undershoot MIN_SPEED for one step; a car does not reverse here
            self.ego.speed = max(self.ego.speed, self.speed_range[0])
        self.acceleration = (self.ego.speed - speed_before) / self.dt
        self.steps += 1

        obs, info = self._observe()
        progress = self.ego.position[0] - x_before
        reward = self.progress_weight * (self.ego.speed / self.speed_range[1]) * progress / self.goal_distance
        if info["collision"]:
            reward -= self.collision_penalty
        elif info["off_road"]:
            reward -= self.off_road_penalty
        elif info["goal_reached"]:
            reward += self.goal_reward
        elif info["time_out"]:
            reward -= self.time_out_penalty
        terminated = info["collision"] or info["off_road"] or info["goal_reached"] or info["time_out"]
        return obs, float(reward), bool(terminated), False, info

    # ------------------------------------------------------------------ features

    def other_cars(self) -> tuple[NDArray[np.int32], NDArray[np.float32]]:
        """Ids and ``x, y, speed, heading`` of the replayed cars at the current frame (the ego's car left out)."""
        ids, states = self.scenario.frame(self.start_frame + self.steps)
        keep = ids != self.ego_id
        return ids[keep], states[keep]

    def _observe(self) -> tuple[NDArray[np.float32], dict[str, Any]]:
        assert self.ego is not None
        ego_x, ego_y = float(self.ego.position[0]), float(self.ego.position[1])
        ego_speed, ego_heading = float(self.ego.speed), float(self.ego.heading)
        ego_length, ego_width = self.ego.LENGTH, self.ego.WIDTH
        width, r = self.lane_width, self.sensing_range
        lane = int(np.clip(np.rint(ego_y / width), 0, self.n_lanes - 1))
        centre = lane * width

        ids, states = self.other_cars()
        dx = states[:, 0] - ego_x
        near = np.abs(dx) <= r
        ids, states, dx = ids[near], states[near], dx[near]
        lengths, widths = self.scenario.lengths[ids], self.scenario.widths[ids]
        lanes = np.rint(states[:, 1] / width)
        half_lengths = (lengths + ego_length) / 2

        gaps = np.full(6, r)  # lead left/same/right, follow left/same/right
        rel_speeds = np.zeros(6)
        for k, offset in enumerate((-1, 0, 1)):
            in_lane = lanes == lane + offset
            ahead = np.flatnonzero(in_lane & (dx > 0))
            if len(ahead):
                j = ahead[np.argmin(dx[ahead])]
                gaps[k] = min(dx[j] - half_lengths[j], r)
                rel_speeds[k] = states[j, 2] - ego_speed
            behind = np.flatnonzero(in_lane & (dx <= 0))
            if len(behind):
                j = behind[np.argmax(dx[behind])]
                gaps[3 + k] = min(-dx[j] - half_lengths[j], r)
                rel_speeds[3 + k] = states[j, 2] - ego_speed

        # Collision: bounding-box prefilter, then highway-env's separating-axis test on the rectangles
        collision = False
        reach = (lengths + widths + ego_length + ego_width) / 2
        for j in np.flatnonzero((np.abs(dx) < reach) & (np.abs(states[:, 1] - ego_y) < reach)):
            other = _polygon(states[j, 0], states[j, 1], states[j, 3], lengths[j], widths[j])
            mine = _polygon(ego_x, ego_y, ego_heading, ego_length, ego_width)
            if utils.are_polygons_intersecting(mine, other, np.zeros(2), np.zeros(2))[0]:
                collision = True
                break
        # Off road: a corner of the ego beyond a road edge
        half_extent = (ego_length * abs(np.sin(ego_heading)) + ego_width * abs(np.cos(ego_heading))) / 2
        off_road = ego_y - half_extent < self.left_edge or ego_y + half_extent > self.right_edge
        goal_distance = self.start_x + self.goal_distance - ego_x
        goal_reached = goal_distance <= 0 and not (collision or off_road)
        time_out = self.steps >= self.max_steps and not (collision or off_road or goal_reached)

        obs = np.array(
            [
                ego_speed,
                self.acceleration,
                ego_heading,
                self.steering,
                ego_y - centre,
                ego_y - (centre - width / 2),
                centre + width / 2 - ego_y,
                ego_y - self.left_edge,
                self.right_edge - ego_y,
                *gaps,
                *rel_speeds,
                goal_distance,
                (self.max_steps - self.steps) * self.dt,
            ],
            dtype=np.float32,
        )
        cost_velocity = float(ego_speed > self.speed_limit)
        cost_distance = float(gaps[1] < self.min_gap)
        per_constraint = {"velocity": cost_velocity, "distance": cost_distance}
        info = {
            "cost": max(per_constraint[name] for name in self.constraints),
            "cost_velocity": cost_velocity,
            "cost_distance": cost_distance,
            # Each of this env's own constraints apart, for the per-constraint violation rates of evaluations
            "constraint_costs": {name: per_constraint[name] for name in self.constraints},
            "ego_speed": ego_speed,
            "lead_gap": float(gaps[1]),
            "collision": collision,
            "off_road": bool(off_road),
            "time_out": bool(time_out),
            "goal_reached": bool(goal_reached),
            "is_success": bool(goal_reached),
        }
        return obs, info

    # ------------------------------------------------------------------ rendering

    def render(self) -> NDArray[np.uint8] | None:
        """
        :return: An RGB image (height x width x 3) of the road around the ego when ``render_mode="rgb_array"``
        """
        if self.render_mode is None or self.ego is None:
            return None
        # highway-env's drawing code; imported here so that pygame is only loaded when rendering
        import pygame
        from highway_env.road.graphics import RoadGraphics, WorldSurface
        from highway_env.vehicle.graphics import VehicleGraphics

        size = (600, 150)
        if self._surface is None:
            self._surface = WorldSurface(size, 0, pygame.Surface(size))
            self._surface.centering_position = [0.3, 0.5]
        surface = self._surface
        surface.move_display_window_to(self.ego.position)
        RoadGraphics.display(self.road, surface)
        goal_x, goal_y = surface.pos2pix(self.start_x + self.goal_distance, self.left_edge)
        pygame.draw.rect(
            surface, surface.YELLOW, (goal_x, goal_y, surface.pix(2.0), surface.pix(self.right_edge - self.left_edge))
        )
        ids, states = self.other_cars()
        for car, (x, y, speed, heading) in zip(ids, states, strict=True):
            if abs(x - self.ego.position[0]) < 150:
                vehicle = Vehicle(self.road, [float(x), float(y)], float(heading), float(speed))
                vehicle.LENGTH, vehicle.WIDTH = float(self.scenario.lengths[car]), float(self.scenario.widths[car])
                vehicle.color = (200, 60, 60)
                VehicleGraphics.display(vehicle, surface, offscreen=True)
        VehicleGraphics.display(self.ego, surface, offscreen=True)
        return np.ascontiguousarray(np.moveaxis(pygame.surfarray.array3d(surface), 0, 1))
