"""
A rule-based driver for the highway environments: reads only the observation (the documented layout).

It follows the lead car with IDM towards a target speed, changes lanes when a neighbouring lane is
faster, and steers along lane centres. With ``target_speed`` above 40 m/s and short gaps it is a
*greedy* driver that ignores both constraints; lowering ``target_speed`` and raising ``min_gap`` gives
drivers that respect them. Used to check that each constraint costs reward, and in tests.
"""

import numpy as np
from numpy.typing import NDArray

from sb3_icrl.envs.highway.env import FEATURE_INDEX as F


class RuleBasedDriver:
    """
    :param target_speed: Speed it drives at on a free road [m/s]
    :param min_gap: Standstill gap it keeps to the lead car [m]
    :param time_headway: Extra gap per m/s of its speed [s]
    :param change_lanes: Whether it overtakes
    :param lane_change_gap: Gap it wants ahead of and behind it in the new lane [m]
    :param lane_width: Lane width of the environment [m]
    :param steering_max: The environment's steering range [rad]
    :param acceleration_max: The environment's acceleration range [m/s^2]
    :param length: Length of the ego car [m]
    """

    def __init__(
        self,
        target_speed: float = 60.0,
        min_gap: float = 2.0,
        time_headway: float = 0.3,
        change_lanes: bool = True,
        lane_change_gap: float = 5.0,
        lane_width: float = 4.0,
        steering_max: float = 0.05,
        acceleration_max: float = 5.0,
        length: float = 5.0,
    ) -> None:
        self.target_speed, self.min_gap, self.time_headway = target_speed, min_gap, time_headway
        self.change_lanes, self.lane_change_gap = change_lanes, lane_change_gap
        self.lane_width, self.steering_max, self.acceleration_max, self.length = (
            lane_width,
            steering_max,
            acceleration_max,
            length,
        )
        self.target_lane: int | None = None

    def reset(self) -> None:
        """Forget the lane it was heading for (call at the start of each episode)."""
        self.target_lane = None

    def _idm(self, speed: float, gap: float, rel_speed: float) -> float:
        s_star = self.min_gap + max(0.0, speed * self.time_headway - speed * rel_speed / (2 * np.sqrt(3.0 * 5.0)))
        return self.acceleration_max * (1 - (speed / self.target_speed) ** 4 - (s_star / max(gap, 0.1)) ** 2)

    def __call__(self, obs: NDArray) -> NDArray[np.float32]:
        """
        :param obs: One observation of the environment
        :return: The action ``[acceleration, steering]`` in ``[-1, 1]``
        """
        speed, heading = float(obs[F["ego_speed"]]), float(obs[F["ego_heading"]])
        y = float(obs[F["left_road_edge_distance"]]) - self.lane_width / 2  # lane 0 is centred at y = 0
        lane = round(y / self.lane_width)
        n_lanes = round((obs[F["left_road_edge_distance"]] + obs[F["right_road_edge_distance"]]) / self.lane_width)
        if self.target_lane is None:
            self.target_lane = lane
        gaps = obs[[F["lead_gap_left"], F["lead_gap_same"], F["lead_gap_right"]]]
        rels = obs[[F["lead_rel_speed_left"], F["lead_rel_speed_same"], F["lead_rel_speed_right"]]]
        back = obs[[F["follow_gap_left"], F["follow_gap_same"], F["follow_gap_right"]]]
        accelerations = [self._idm(speed, float(g), float(r)) for g, r in zip(gaps, rels, strict=True)]
        settled = self.target_lane == lane and abs(y - lane * self.lane_width) < 0.5
        if self.change_lanes and settled:
            for side, k in ((-1, 0), (1, 2)):
                # The cars behind do not react: leave them room for two seconds of closing speed
                follow_rel = float(obs[F["follow_rel_speed_left"] + k])
                free = gaps[k] > self.lane_change_gap and back[k] > self.lane_change_gap + 2.0 * max(follow_rel, 0.0)
                if 0 <= lane + side < n_lanes and free and accelerations[k] > accelerations[1] + 0.3:
                    self.target_lane = lane + side
                    break
        acceleration = accelerations[1]
        if self.target_lane != lane:  # mind the new lane's leader too while moving over
            acceleration = min(acceleration, accelerations[1 + self.target_lane - lane])
        error = self.target_lane * self.lane_width - y
        # At most 1.5 m/s sideways, so that lane changes do not overshoot at high speed
        limit = min(0.08, 1.5 / max(speed, 1.0))
        heading_wanted = float(np.clip(0.5 * error / max(speed, 1.0), -limit, limit))
        steering = (heading_wanted - heading) / 0.4 * self.length / max(speed, 1.0)
        return np.array(
            [np.clip(acceleration / self.acceleration_max, -1, 1), np.clip(steering / self.steering_max, -1, 1)],
            dtype=np.float32,
        )
