"""
Recorded traffic for the highway environments: generated once with IDM + MOBIL, stored, replayed.

The paper replays HighD recordings (German highways, drone footage, 25 Hz) through CommonRoad-RL. Both
are unavailable here, so each :class:`Scenario` is a recording of *simulated* traffic on a straight
highway stretch, made once from a seed by :func:`record_scenario` and shipped as a ``.npz`` file:

- Every car follows the Intelligent Driver Model (the parameters of highway-env's ``IDMVehicle``
  apart from a per-car desired speed, time gap and minimum gap) and changes lanes with a MOBIL-like
  rule (incentive, safety check on the new follower, keep-right bias). Faster drivers, with shorter
  time gaps, enter further left; 30 % of the vehicles entering the rightmost lane are 12 m trucks,
  slower, which stay there. In dense traffic the lanes thus flow at different speeds.
  Vehicles enter upstream with a spacing drawn from the density and leave downstream; the first
  ``warmup`` seconds are simulated but not stored.
- Only the stretch ``[-100, road_length + 100]`` m is stored, one row per (frame, car):
  ``x, y, speed, heading`` as float32, in the long format of HighD's ``tracks.csv``
  (``frame_offsets[k]:frame_offsets[k + 1]`` are the rows of frame ``k``).
- The environment takes over one recorded car (the *ego*, like the paper's env does with a HighD
  car) from the frame where it crosses ``x = 0``; the other cars replay their recorded tracks and
  never react to the ego.

How this differs from HighD: the drivers are a model, not people (no human variability beyond the
drawn parameters, no accidents, smooth lane changes of about 3 s); one road layout (3 lanes of
4 m, straight); 5 Hz instead of 25 Hz; and the densities are chosen (``sparse``/``dense``) rather
than observed.
"""

import glob
import os
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from sb3_icrl.common.utils import atomic_save_npz

#: Shipped recordings: ``scenarios/<density>_<split>_<index>.npz``
SCENARIO_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "scenarios")
SPLITS = ("train", "test")
#: Vehicles per km and lane at the upstream entry. Sparse: free flow, about 30 m/s, where breaking the
#: speed limit pays; dense: about 12-21 m/s from the right lane to the left one, gaps near 20 m, where
#: short gaps pay (``benchmarks/highway_greedy.py`` measures both)
DENSITIES: dict[str, float] = {"sparse": 8.0, "dense": 50.0}
LANE_WIDTH = 4.0  # highway-env's StraightLane.DEFAULT_WIDTH
STORE_MARGIN = 100.0  # stored beyond both ends of the stretch: the sensing range of the env
FORMAT_VERSION = 1

# IDM (highway-env's IDMVehicle: COMFORT_ACC_MAX, COMFORT_ACC_MIN, DELTA) and MOBIL parameters
IDM_ACC = 3.0
IDM_DECEL = 5.0
IDM_DELTA = 4.0
MAX_BRAKE = 9.0
MOBIL_POLITENESS = 0.3
MOBIL_THRESHOLD = 0.3
MOBIL_SAFE_DECEL = 3.0
MOBIL_KEEP_RIGHT = 0.1
MOBIL_MIN_GAP = 4.0
LANE_CHANGE_CHECK_PERIOD = 2.0  # [s] mean time between lane-change checks of a car
LATERAL_GAIN = 1.5  # [1/s] lateral speed per metre to the target lane centre
LATERAL_SPEED_MAX = 1.5  # [m/s]: a lane change takes about 3.5 s


@dataclass
class Scenario:
    """
    One recording of traffic on a straight highway stretch, stored in long format.

    :param dt: Time between frames [s]
    :param n_lanes: Number of lanes (lane ``i`` is centred at ``y = i * lane_width``; lane 0 is the leftmost)
    :param lane_width: Lane width [m]
    :param road_length: The stretch is ``[0, road_length]`` m; rows cover ``[-100, road_length + 100]``
    :param density: Vehicles per km and lane the recording was made with
    :param seed: Seed of the recording
    :param lengths: Length of each car [m], indexed by car id
    :param widths: Width of each car [m], indexed by car id
    :param frame_offsets: ``frame_offsets[k]:frame_offsets[k + 1]`` are the rows of frame ``k``
    :param car_ids: Car id of each row
    :param states: ``x, y, speed, heading`` of each row (float32)
    """

    dt: float
    n_lanes: int
    lane_width: float
    road_length: float
    density: float
    seed: int
    lengths: NDArray[np.float32]
    widths: NDArray[np.float32]
    frame_offsets: NDArray[np.int64]
    car_ids: NDArray[np.int32]
    states: NDArray[np.float32]

    @property
    def n_frames(self) -> int:
        return len(self.frame_offsets) - 1

    def frame(self, k: int) -> tuple[NDArray[np.int32], NDArray[np.float32]]:
        """
        :param k: Frame index
        :return: Car ids and ``x, y, speed, heading`` rows of the cars stored in frame ``k``
        """
        start, stop = self.frame_offsets[k], self.frame_offsets[k + 1]
        return self.car_ids[start:stop], self.states[start:stop]

    def ego_candidates(self, n_frames: int, max_length: float = 6.0) -> NDArray[np.int64]:
        """
        Cars that can be taken over as ego: those that cross ``x = 0`` with ``n_frames`` recorded frames left.

        :param n_frames: Frames the episode may last
        :param max_length: Longer vehicles (trucks) are never the ego: it drives like a car
        :return: Array of ``(car id, frame)`` pairs, the frame being the first with ``x >= 0``
        """
        frames = np.repeat(np.arange(self.n_frames), np.diff(self.frame_offsets))
        inside = self.states[:, 0] >= 0.0
        ids, frames_in = self.car_ids[inside], frames[inside]
        first = np.full(len(self.lengths), -1, dtype=np.int64)
        # Rows are in frame order, so the first row of each car inside the stretch is its entry
        order = np.unique(ids, return_index=True)
        first[order[0]] = frames_in[order[1]]
        # Cars already on the stretch when the recording starts did not enter it
        present_at_start = self.car_ids[self.frame_offsets[0] : self.frame_offsets[1]]
        x_start = self.states[self.frame_offsets[0] : self.frame_offsets[1], 0]
        first[present_at_start[x_start >= 0.0]] = -1
        ok = (first >= 0) & (first + n_frames < self.n_frames) & (self.lengths <= max_length)
        return np.stack([np.flatnonzero(ok), first[ok]], axis=1)

    def lead_gap(self, car: int, frame: int) -> float:
        """
        :param car: Car id
        :param frame: Frame index (the car must be stored in it)
        :return: Bumper-to-bumper gap to the nearest car ahead in its lane (nearest lane centre), ``inf`` if none
        """
        ids, states = self.frame(frame)
        me = np.flatnonzero(ids == car)[0]
        lanes = np.rint(states[:, 1] / self.lane_width)
        ahead = np.flatnonzero((lanes == lanes[me]) & (states[:, 0] > states[me, 0]))
        if not len(ahead):
            return float("inf")
        j = ahead[np.argmin(states[ahead, 0])]
        return float(states[j, 0] - states[me, 0] - (self.lengths[ids[j]] + self.lengths[car]) / 2)

    def save(self, path: str) -> None:
        """
        :param path: ``.npz`` file to write (compressed)
        """
        arrays = {
            "format_version": np.int64(FORMAT_VERSION),
            "meta": np.array([self.dt, self.n_lanes, self.lane_width, self.road_length, self.density, self.seed]),
            "lengths": self.lengths,
            "widths": self.widths,
            "frame_offsets": self.frame_offsets,
            "car_ids": self.car_ids,
            "states": self.states,
        }
        atomic_save_npz(path, arrays, compressed=True)

    @classmethod
    def load(cls, path: str) -> "Scenario":
        """
        :param path: ``.npz`` file written by :meth:`save`
        :return: The recording
        """
        with np.load(path) as data:
            if int(data["format_version"]) != FORMAT_VERSION:
                raise ValueError(f"{path}: scenario format {int(data['format_version'])}, expected {FORMAT_VERSION}")
            dt, n_lanes, lane_width, road_length, density, seed = data["meta"].tolist()
            return cls(
                dt=dt,
                n_lanes=int(n_lanes),
                lane_width=lane_width,
                road_length=road_length,
                density=density,
                seed=int(seed),
                lengths=data["lengths"],
                widths=data["widths"],
                frame_offsets=data["frame_offsets"],
                car_ids=data["car_ids"],
                states=data["states"],
            )


def scenario_files(density: str, split: str, directory: str = SCENARIO_DIR) -> list[str]:
    """
    :param density: ``"sparse"``, ``"dense"`` or ``"mixed"`` (both)
    :param split: ``"train"`` or ``"test"``
    :param directory: Folder holding the ``<density>_<split>_<index>.npz`` files
    :return: Sorted paths of the matching recordings
    """
    if split not in SPLITS:
        raise ValueError(f"Unknown scenario split {split!r}, expected one of {SPLITS}")
    if density != "mixed" and density not in DENSITIES:
        raise ValueError(f"Unknown traffic density {density!r}, expected one of {(*DENSITIES, 'mixed')}")
    densities = list(DENSITIES) if density == "mixed" else [density]
    paths = sorted(p for d in densities for p in glob.glob(os.path.join(directory, f"{d}_{split}_*.npz")))
    if not paths:
        raise FileNotFoundError(
            f"No {density} {split} scenarios in {directory} (generate them: python -m sb3_icrl.envs.highway)"
        )
    return paths


def load_scenarios(density: str, split: str, directory: str = SCENARIO_DIR) -> list[Scenario]:
    """
    :param density: ``"sparse"``, ``"dense"`` or ``"mixed"``
    :param split: ``"train"`` or ``"test"``
    :param directory: Folder of the recordings
    :return: The recordings, in file-name order
    """
    return [Scenario.load(path) for path in scenario_files(density, split, directory)]


def _idm(speed: NDArray, desired: NDArray, gap: NDArray, closing: NDArray, headway: NDArray, min_gap: NDArray) -> NDArray:
    """IDM acceleration; ``gap`` is bumper to bumper (``inf`` without a leader), ``closing`` = own speed - leader's."""
    s_star = min_gap + np.maximum(0.0, speed * headway + speed * closing / (2.0 * np.sqrt(IDM_ACC * IDM_DECEL)))
    with np.errstate(divide="ignore"):
        interaction = (s_star / np.maximum(gap, 0.1)) ** 2
    return np.maximum(IDM_ACC * (1.0 - (speed / desired) ** IDM_DELTA - interaction), -MAX_BRAKE)


class _Traffic:
    """Vehicle arrays of the recorder, one entry per vehicle ever spawned (grown by doubling)."""

    FIELDS = ("x", "y", "lane", "target_y", "speed", "desired", "headway", "min_gap", "length", "width", "active")

    def __init__(self, rng: np.random.Generator, n_lanes: int) -> None:
        self.rng, self.n_lanes = rng, n_lanes
        self.n = 0
        self.x, self.y, self.lane, self.target_y, self.speed, self.desired = (np.zeros(64) for _ in range(6))
        self.headway, self.min_gap, self.length, self.width = (np.zeros(64) for _ in range(4))
        self.lane = self.lane.astype(np.int64)
        self.active = np.zeros(64, dtype=bool)

    def spawn(self, x: float, lane: int, leader_speed: float | None) -> None:
        if self.n == len(self.x):
            for name in self.FIELDS:
                old = getattr(self, name)
                setattr(self, name, np.concatenate([old, np.zeros_like(old)]))
        i, self.n = self.n, self.n + 1
        # Trucks keep to the rightmost lane and faster drivers enter further left, as on German highways
        truck = lane == self.n_lanes - 1 and self.rng.random() < 0.3
        fast = 1.0 - lane / max(self.n_lanes - 1, 1)
        self.desired[i] = self.rng.uniform(22.0, 26.0) if truck else self.rng.uniform(25.0, 32.0) + 6.0 * fast
        self.speed[i] = self.desired[i] if leader_speed is None else min(self.desired[i], leader_speed)
        self.x[i], self.lane[i] = x, lane
        self.y[i] = self.target_y[i] = lane * LANE_WIDTH
        # Shorter time gaps further left: in dense traffic the left lane is the fast one, with short gaps
        self.headway[i] = self.rng.uniform(1.5, 2.2) if truck else self.rng.uniform(0.6, 1.0) + 0.6 * (1.0 - fast)
        self.min_gap[i] = self.rng.uniform(2.0, 4.0)
        self.length[i], self.width[i] = (12.0, 2.5) if truck else (5.0, 2.0)
        self.active[i] = True

    def occupancy(self, ids: NDArray) -> tuple[NDArray, NDArray]:
        """(vehicle, lane) pairs: a vehicle occupies its target lane and, while changing, the lane it leaves."""
        lanes = np.rint(self.y[ids] / LANE_WIDTH).astype(np.int64)
        leaving = lanes != self.lane[ids]
        return np.concatenate([ids, ids[leaving]]), np.concatenate([self.lane[ids], lanes[leaving]])

    def gap(self, i: NDArray, lead: NDArray) -> NDArray:
        """Bumper-to-bumper gap from ``i`` to ``lead`` (``inf`` where ``lead`` is -1)."""
        safe = np.where(lead >= 0, lead, i)
        return np.where(lead >= 0, self.x[safe] - self.x[i] - (self.length[safe] + self.length[i]) / 2, np.inf)

    def acceleration(self, i: NDArray, lead: NDArray) -> NDArray:
        """IDM acceleration of vehicles ``i`` behind ``lead`` (-1: free road)."""
        safe = np.where(lead >= 0, lead, i)
        closing = np.where(lead >= 0, self.speed[i] - self.speed[safe], 0.0)
        return _idm(self.speed[i], self.desired[i], self.gap(i, lead), closing, self.headway[i], self.min_gap[i])


def _neighbours(
    x: NDArray, occupants: tuple[NDArray, NDArray], queries: NDArray, query_lanes: NDArray, n_lanes: int
) -> tuple[NDArray, NDArray]:
    """
    Nearest occupant ahead of and behind each query vehicle in the query lane (-1 when none).

    Sorted positions per lane and ``searchsorted``: O(N log N), unlike highway-env's O(N^2) search.

    :param x: Longitudinal positions of all vehicles
    :param occupants: (vehicle, lane) pairs from :meth:`_Traffic.occupancy`
    :param queries: Vehicles asking
    :param query_lanes: Lane each query looks in
    :param n_lanes: Number of lanes
    """
    leader = np.full(len(queries), -1)
    follower = np.full(len(queries), -1)
    occ_ids, occ_lanes = occupants
    for lane_index in range(n_lanes):
        asking = np.flatnonzero(query_lanes == lane_index)
        in_lane = occ_ids[occ_lanes == lane_index]
        if not len(asking) or not len(in_lane):
            continue
        order = in_lane[np.argsort(x[in_lane], kind="stable")]
        xs = x[order]
        me = queries[asking]
        # side="right": a vehicle is never its own leader
        pos = np.searchsorted(xs, x[me], side="right")
        has_leader = pos < len(order)
        leader[asking[has_leader]] = order[pos[has_leader]]
        behind = pos - 1
        behind = np.where((behind >= 0) & (order[np.maximum(behind, 0)] == me), behind - 1, behind)
        has_follower = behind >= 0
        follower[asking[has_follower]] = order[behind[has_follower]]
    return leader, follower


def record_scenario(
    seed: int,
    density: float,
    duration: float = 120.0,
    dt: float = 0.2,
    road_length: float = 500.0,
    n_lanes: int = 3,
    warmup: float = 40.0,
    substeps: int = 2,
) -> Scenario:
    """
    Simulate IDM/MOBIL traffic and record it.

    :param seed: Seed of everything random in the recording
    :param density: Vehicles per km and lane at the entry
    :param duration: Recorded time [s]
    :param dt: Time between stored frames [s]
    :param road_length: Length of the stretch [m] (the env puts its goal ``sensing range`` before its end)
    :param n_lanes: Number of lanes
    :param warmup: Simulated time before the first stored frame [s]
    :param substeps: Integration steps per frame
    :return: The recording
    """
    if density <= 0:
        raise ValueError(f"density must be > 0 vehicles/km/lane, got {density}")
    rng = np.random.default_rng(seed)
    t = _Traffic(rng, n_lanes)
    entry, exit_ = -STORE_MARGIN - 300.0, road_length + STORE_MARGIN + 50.0
    mean_spacing = 1000.0 / density

    def next_spacing() -> float:
        return float(mean_spacing * rng.uniform(0.6, 1.4))

    # Initial traffic along the whole road, then the entry keeps feeding it
    for lane_index in range(n_lanes):
        x = exit_ - rng.uniform(0.0, mean_spacing)
        while x > entry:
            t.spawn(x, lane_index, None)
            x -= next_spacing()
    spawn_gap = [next_spacing() for _ in range(n_lanes)]

    h = dt / substeps
    n_warmup = round(warmup / dt)
    n_frames = round(duration / dt) + 1
    rows_ids: list[NDArray] = []
    rows_states: list[NDArray] = []
    offsets = [0]
    for frame in range(n_warmup + n_frames):
        for _ in range(substeps):
            ids = np.flatnonzero(t.active[: t.n])
            occupants = t.occupancy(ids)
            # Follow the nearest leader in any lane the vehicle occupies (both lanes while changing)
            lead_target, _ = _neighbours(t.x, occupants, ids, t.lane[ids], n_lanes)
            current = np.rint(t.y[ids] / LANE_WIDTH).astype(np.int64)
            lead_current, _ = _neighbours(t.x, occupants, ids, current, n_lanes)
            acc = np.zeros(t.n)
            acc[ids] = np.minimum(t.acceleration(ids, lead_target), t.acceleration(ids, lead_current))

            # MOBIL-like lane changes, checked now and then by vehicles that are not changing lanes
            settled = (t.lane[ids] == current) & (np.abs(t.y[ids] - t.target_y[ids]) < 0.2)
            checking = ids[settled & (t.length[ids] < 10.0) & (rng.random(len(ids)) < h / LANE_CHANGE_CHECK_PERIOD)]
            for direction in (-1, 1):
                movers = checking[(t.lane[checking] + direction >= 0) & (t.lane[checking] + direction < n_lanes)]
                movers = movers[t.lane[movers] == np.rint(t.target_y[movers] / LANE_WIDTH)]  # not changed this step
                if not len(movers):
                    continue
                new_leader, new_follower = _neighbours(t.x, occupants, movers, t.lane[movers] + direction, n_lanes)
                gain = t.acceleration(movers, new_leader) - acc[movers]
                has_f = new_follower >= 0
                follower = np.where(has_f, new_follower, movers)
                follower_after = np.where(has_f, t.acceleration(follower, np.where(has_f, movers, -1)), 0.0)
                follower_loss = np.where(has_f, acc[follower] - follower_after, 0.0)
                bias = MOBIL_KEEP_RIGHT if direction > 0 else -MOBIL_KEEP_RIGHT
                incentive = gain - MOBIL_POLITENESS * follower_loss + bias
                gap_behind = t.gap(follower, np.where(has_f, movers, -1))
                safe = (follower_after > -MOBIL_SAFE_DECEL) & (gap_behind > MOBIL_MIN_GAP)
                safe &= t.gap(movers, new_leader) > MOBIL_MIN_GAP
                change = movers[(incentive > MOBIL_THRESHOLD) & safe]
                t.lane[change] += direction
                t.target_y[change] = t.lane[change] * LANE_WIDTH

            # Semi-implicit Euler; lateral motion towards the target lane centre
            t.speed[ids] = np.maximum(t.speed[ids] + acc[ids] * h, 0.0)
            t.x[ids] += t.speed[ids] * h
            t.y[ids] += np.clip(LATERAL_GAIN * (t.target_y[ids] - t.y[ids]), -LATERAL_SPEED_MAX, LATERAL_SPEED_MAX) * h
            t.active[ids[t.x[ids] > exit_]] = False

            # Entry: a new vehicle once the last one in the lane is far enough (and at a safe gap)
            ids = np.flatnonzero(t.active[: t.n])
            for lane_index in range(n_lanes):
                in_lane = ids[(t.lane[ids] == lane_index) | (np.rint(t.y[ids] / LANE_WIDTH) == lane_index)]
                last = in_lane[np.argmin(t.x[in_lane])] if len(in_lane) else None
                room = np.inf if last is None else t.x[last] - t.length[last] / 2 - entry
                speed = None if last is None else float(t.speed[last])
                if room > max(spawn_gap[lane_index], 10.0 + 1.2 * (speed or 0.0)):
                    t.spawn(entry, lane_index, speed)
                    spawn_gap[lane_index] = next_spacing()

        if frame < n_warmup:
            continue
        active = np.flatnonzero(t.active[: t.n])
        stored = active[(t.x[active] >= -STORE_MARGIN) & (t.x[active] <= road_length + STORE_MARGIN)]
        lateral = np.clip(LATERAL_GAIN * (t.target_y[stored] - t.y[stored]), -LATERAL_SPEED_MAX, LATERAL_SPEED_MAX)
        heading = np.arctan2(lateral, np.maximum(t.speed[stored], 1e-3))
        rows_ids.append(stored.astype(np.int32))
        rows_states.append(np.stack([t.x[stored], t.y[stored], t.speed[stored], heading], axis=1).astype(np.float32))
        offsets.append(offsets[-1] + len(stored))

    return Scenario(
        dt=dt,
        n_lanes=n_lanes,
        lane_width=LANE_WIDTH,
        road_length=road_length,
        density=density,
        seed=seed,
        lengths=t.length[: t.n].astype(np.float32),
        widths=t.width[: t.n].astype(np.float32),
        frame_offsets=np.asarray(offsets, dtype=np.int64),
        car_ids=np.concatenate(rows_ids),
        states=np.concatenate(rows_states),
    )
