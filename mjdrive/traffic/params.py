"""Road-user kinds, behaviour constants (TrafficConfig), the ego as traffic sees it, and slot helpers."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from mjdrive.config import Config, ConfigError, param
from mjdrive.world import TrafficSlot

PATH = 4  # lanes held in each vehicle's planned path (the current one and the next three)
HIDDEN_Z = -50.0  # [m] where inactive slots wait (below the ground, never seen, never touched)
N_TRACKS = 3  # pedestrian tracks per crosswalk


@dataclass(frozen=True)
class RoadUserType:
    """A kind of road user: box half sizes [m], colour, desired speed range [m/s] (walking speed for
    pedestrians) and IDM parameters: max acceleration a [m/s^2], comfortable deceleration b [m/s^2],
    time headway T [s]; preferred lateral offset range in the lane [m] (> 0 left)."""

    name: str
    half_size: tuple[float, float, float]
    rgba: tuple[float, float, float, float]
    speed: tuple[float, float]
    accel: float = 1.5
    decel: float = 2.5
    headway: float = 1.0
    lateral: tuple[float, float] = (0.0, 0.0)

    @property
    def slot(self) -> TrafficSlot:
        return TrafficSlot(self.name, self.half_size, self.rgba)

    @property
    def is_vehicle(self) -> bool:
        return self.name != "pedestrian"


ROAD_USER_TYPES: dict[str, RoadUserType] = {
    "car": RoadUserType("car", (2.25, 0.9, 0.75), (0.75, 0.15, 0.12, 1.0), (6.5, 8.33), 1.5, 2.5, 1.0,
                        (-0.2, 0.2)),
    "motorcycle": RoadUserType("motorcycle", (1.1, 0.4, 0.7), (0.15, 0.15, 0.18, 1.0), (7.0, 8.33), 2.5, 3.0,
                               0.8, (-0.6, 0.6)),
    "bicycle": RoadUserType("bicycle", (0.9, 0.3, 0.85), (0.95, 0.75, 0.1, 1.0), (3.5, 5.5), 1.0, 2.0, 1.0,
                            (-0.9, -0.8)),
    "pedestrian": RoadUserType("pedestrian", (0.25, 0.3, 0.88), (0.2, 0.35, 0.75, 1.0), (1.1, 1.6)),
}  # fmt: skip
KIND_NAMES = tuple(ROAD_USER_TYPES)
KIND_INDEX = {name: i for i, name in enumerate(KIND_NAMES)}


@dataclass(frozen=True)
class TrafficConfig(Config):
    """Behaviour constants shared by every road user (validated; `TrafficConfig.from_dict` takes a dict)."""

    min_gap: float = param(2.5, "IDM s0: the study's safe distance to the vehicle ahead", "m", ge=0.5, le=20.0)
    stop_gap: float = param(0.5, "IDM s0 in front of a stop line", "m", ge=0.0, le=10.0)
    max_decel: float = param(8.0, "emergency braking limit", "m/s^2", gt=0.0, le=15.0)
    lateral_accel: float = param(2.0, "curve speed: v <= sqrt(lateral_accel / curvature)", "m/s^2", gt=0.0, le=10.0)
    accept_gap: float = param(3.5, "an entering vehicle goes if no priority vehicle reaches the merge sooner", "s",
                              ge=0.0, le=20.0)
    merge_clearance: float = param(5.0, "... and none is nearer than this (bumper to merge point)", "m",
                                   ge=0.0, le=50.0)
    merge_speed: float = param(3.0, "slower circulating vehicles count as this fast in the gap check", "m/s",
                               ge=0.0, le=20.0)
    yield_speed: float = param(2.5, "entering vehicles reach their yield line no faster than this", "m/s",
                               gt=0.0, le=20.0)
    corridor_range: float = param(25.0, "how far ahead the corridor check looks", "m", gt=0.0, le=100.0)
    corridor_margin: float = param(0.3, "lateral margin of the corridor", "m", ge=0.0, le=3.0)
    lane_change_rate: tuple[float, float] = param((0.5, 0.5), "lane changes to the right, to the left neighbour",
                                                  "1/s", ge=0.0, le=10.0)
    lane_change_length: float = param(15.0, "distance over which a lane change moves across", "m", gt=1.0, le=100.0)
    spawn_clear: float = param(14.0, "a source spawns only if nothing is this close to its start", "m",
                               ge=0.0, le=100.0)
    crosswalk_margin: float = param(1.0, "vehicles stop this far before a crosswalk / a pedestrian's band", "m",
                                    ge=0.0, le=10.0)
    kerb: float = param(0.9, "where pedestrians wait, beyond the end of the crosswalk", "m", ge=0.0, le=5.0)
    pedestrian_wait: tuple[float, float] = param((2.0, 10.0), "wait at the kerb before looking for a gap "
                                                 "(uniform, min and max)", "s", ge=0.0, le=120.0)
    respawn: bool = param(True, "vehicles that left the map re-enter at the sources")
    spawn_rate: float = param(0.0, "urban rules: each waiting vehicle re-enters at this rate (0: as soon as a "
                              "source is clear)", "1/s", ge=0.0, le=10.0)
    critical_gap_crossing: float = param(2.0, "urban rules: a yielding vehicle crosses if every priority agent "
                                         "reaches the zone this long after it has cleared it", "s", ge=0.0, le=20.0)
    impatience: float = param(20.0, "urban rules: waiting this long brings a vehicle's critical gap to zero", "s",
                              gt=0.0, le=600.0)
    critical_gap_merge: float = param(1.5, "urban rules: ... and merges if they reach the merge point this long "
                                      "after it", "s", ge=0.0, le=20.0)
    lane_changes: str = param("random", "lane changes at random rates (roundabout) or by intention with a "
                              "MOBIL-like safety check and a signalling phase (urban rules)",
                              choices=("random", "intention"))
    signal_time: float = param(1.0, "indicator on before an intended lane change starts", "s", ge=0.0, le=10.0)
    safe_decel: float = param(3.0, "MOBIL safety: the new follower never has to brake harder", "m/s^2",
                              gt=0.0, le=10.0)
    courtesy_range: float = param(60.0, "a yielding vehicle opens a gap for agents this close to the merge point (a "
                                  "lane's 40 m taper and a car's length)",
                                  "m", ge=0.0, le=200.0)
    desired_speed: tuple[float, float] | None = param(None, "urban rules: vehicles' maximum speeds drawn in "
                                                      "[min, max] (None: each kind's range)", "m/s", ge=0.5, le=40.0)
    lane_change_intentions: tuple[float, float, float] = param((0.6, 0.2, 0.2), "shares of keep, left, right",
                                                               ge=0.0, le=1.0)
    turn_intentions: tuple[float, float, float] = param((0.4, 0.3, 0.3), "shares of straight, left, right",
                                                        ge=0.0, le=1.0)
    merge_intentions: tuple[float, float] = param((0.5, 0.5), "shares of yield, take way", ge=0.0, le=1.0)
    roundabout_intentions: tuple[float, float] = param((0.5, 0.5), "shares of leaving before, after the ego's exit",
                                                       ge=0.0, le=1.0)
    decision_period: float = param(0.6, "behaviour updates (about a driver's reaction time)", "s", gt=0.0, le=5.0)
    substep: float = param(0.02, "pose resolution (mocap written at this period)", "s", gt=0.0, le=0.2)

    def constants(self) -> Constants:
        return Constants(*(float(getattr(self, name)) for name in Constants._fields))

    def check(self) -> None:
        for name in ("pedestrian_wait", "desired_speed"):
            pair = getattr(self, name)
            if pair is not None and pair[0] > pair[1]:
                raise ConfigError(f"{name}={pair}: the minimum must not exceed the maximum")
        for name in ("lane_change_intentions", "turn_intentions", "merge_intentions", "roundabout_intentions"):
            if sum(getattr(self, name)) <= 0:
                raise ConfigError(f"{name}={getattr(self, name)}: the shares must not all be zero")


# TrafficConfig's numbers as the kernels take them (`TrafficConfig.constants`; units as there)
Constants = NamedTuple("Constants", [(name, float) for name in (
    "min_gap", "stop_gap", "max_decel", "accept_gap", "merge_clearance", "merge_speed", "yield_speed", "corridor_range",
    "corridor_margin", "lane_change_length", "spawn_clear", "crosswalk_margin", "spawn_rate", "critical_gap_crossing",
    "impatience", "critical_gap_merge", "signal_time", "safe_decel", "courtesy_range", "decision_period")])


@dataclass
class EgoState:
    """The ego as traffic sees it: pose [m, m, rad], speed [m/s], size [m], and optionally its place in
    the lane graph: `path` (lane ids from its current lane on, -1 padded) and `s` [m] along path[0]."""

    x: float
    y: float
    yaw: float
    speed: float
    length: float
    width: float
    path: np.ndarray | None = None
    s: float = 0.0


def counts_to_kinds(counts: dict[str, int]) -> list[str]:
    """Slot kinds from counts by kind, vehicles first in ROAD_USER_TYPES order, e.g. {"car": 2, ...}."""
    unknown = set(counts) - set(ROAD_USER_TYPES)
    if unknown:
        raise ValueError(f"unknown road-user kinds {sorted(unknown)}; valid: {', '.join(ROAD_USER_TYPES)}")
    return [name for name in ROAD_USER_TYPES for _ in range(int(counts.get(name, 0)))]


def slots(kinds: Sequence[str]) -> list[TrafficSlot]:
    """The world.TrafficSlot of each kind (for `world.build(traffic=...)`)."""
    return [ROAD_USER_TYPES[k].slot for k in kinds]
