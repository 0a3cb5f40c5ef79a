"""Validated parameters of the urban road pieces (study 002). Every field is checked in `__post_init__`:
a bad value raises ValueError naming the parameter, the value and what is allowed. `from_dict` rejects
unknown keys and lists the valid ones.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

from mjdrive.roads.lane import Marking

LANE_WIDTH_RANGE = (2.5, 5.0)  # [m]
SPEED_LIMIT_RANGE = (1.0, 40.0)  # [m/s]
MAX_LANES = 4  # lanes per direction
TURNS = ("left", "straight", "right")
APPROACH_CLEARANCE = 0.5  # [m] between the merge approach's left edge and the main road's right edge


def check(name: str, value: Any, ok: bool, allowed: str) -> None:
    """Raise ValueError("name=value is not allowed: allowed") unless `ok`."""
    if not ok:
        raise ValueError(f"{name}={value!r} is not allowed: {allowed}")


def check_number(name: str, value: Any, lo: float, hi: float = math.inf, lo_open: bool = False) -> None:
    """A finite real number in [lo, hi] ((lo, hi] if `lo_open`)."""
    real = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
    above = real and (value > lo if lo_open else value >= lo)
    bracket = "(" if lo_open else "["
    check(name, value, above and value <= hi, f"a number in {bracket}{lo:g}, {hi:g}]")


def check_int(name: str, value: Any, lo: int, hi: int) -> None:
    """An int in [lo, hi]."""
    ok = isinstance(value, int) and not isinstance(value, bool) and lo <= value <= hi
    check(name, value, ok, f"an integer in [{lo}, {hi}]")


def _common(p: Any) -> None:
    check_number("lane_width", p.lane_width, *LANE_WIDTH_RANGE)
    check_number("speed_limit", p.speed_limit, *SPEED_LIMIT_RANGE)


class _FromDict:
    @classmethod
    def from_dict(cls, values: dict[str, Any] | None = None):
        """Build from a dict; unknown keys raise ValueError listing the valid ones."""
        values = dict(values or {})
        valid = [f.name for f in fields(cls)]
        unknown = sorted(set(values) - set(valid))
        check("keys", unknown, not unknown, f"keys of {cls.__name__}: {valid}")
        return cls(**values)


@dataclass(frozen=True)
class RoundaboutParams(_FromDict):
    """`roads.roundabout` plus the ego's entry and exit arm (arm a points at angle 2*pi*a/arms)."""

    radius: float = 14.0  # [m] middle of the ring
    lanes: int = 2  # ring lanes
    arms: int = 4
    arm_length: float = 50.0  # [m]
    lane_width: float = 3.5  # [m]
    speed_limit: float = 30 / 3.6  # [m/s]
    crosswalk_offset: float = 6.0  # [m] from the arm's start
    entry_arm: int = 2  # the ego arrives on this arm
    exit_arm: int = 0  # and leaves by this one

    def __post_init__(self) -> None:
        _common(self)
        check_int("lanes", self.lanes, 1, MAX_LANES)
        check_int("arms", self.arms, 3, 8)
        check_number("radius", self.radius, 3.0 + self.lanes * self.lane_width / 2, 100.0)
        check_number("arm_length", self.arm_length, 25.0, 1000.0)
        check_number("crosswalk_offset", self.crosswalk_offset, 0.0, self.arm_length - 3.0)
        check_int("entry_arm", self.entry_arm, 0, self.arms - 1)
        check_int("exit_arm", self.exit_arm, 0, self.arms - 1)
        # `roads.roundabout`: entries meet the outer ring lane at angle delta, which must clear the arm's lane
        delta = min(0.35, 0.3 * 2 * math.pi / self.arms)
        least = (self.lane_width / 2 + 0.5) / math.sin(delta) - (self.lanes - 1) * self.lane_width / 2
        check_number("radius", self.radius, math.ceil(max(least, 3.0 + self.lanes * self.lane_width / 2) * 10) / 10,
                     100.0)


@dataclass(frozen=True)
class OvertakingRoadParams(_FromDict):
    """A straight two-way road whose middle section has `lanes` lanes in the ego's direction (BROKEN lines
    between them: overtaking on the left) and `opposite_lanes` the other way. It starts and ends with
    `entry_lanes` / `exit_lanes` lanes; the extra lanes open and close on the left over `taper_length`."""

    length: float = 200.0  # [m] middle section (all lanes)
    lanes: int = 2
    opposite_lanes: int = 1
    entry_lanes: int = 1
    exit_lanes: int = 1
    taper_length: float = 40.0  # [m] where lanes open / close
    stub_length: float = 10.0  # [m] straight road before the opening and after the closing taper
    lane_width: float = 3.5  # [m]
    speed_limit: float = 50 / 3.6  # [m/s]
    centre_marking: Marking = Marking.SOLID  # between the two directions

    def __post_init__(self) -> None:
        _common(self)
        check_number("length", self.length, 20.0, 5000.0)
        check_int("lanes", self.lanes, 1, MAX_LANES)
        check_int("opposite_lanes", self.opposite_lanes, 0, MAX_LANES)
        check_int("entry_lanes", self.entry_lanes, 1, self.lanes)
        check_int("exit_lanes", self.exit_lanes, 1, self.lanes)
        check_number("taper_length", self.taper_length, 4.0 * self.lane_width * (self.lanes - 1) + 5.0, 500.0)
        check_number("stub_length", self.stub_length, 1.0, 1000.0)
        check("centre_marking", self.centre_marking, self.centre_marking in tuple(Marking),
              f"one of {[m.name for m in Marking]}")


@dataclass(frozen=True)
class CrossroadParams(_FromDict):
    """A four-way crossroad without signals. The ego's approach and the arm straight across are the minor
    road (give-way lines); the main road crosses it at `crossing_angle` (its "left" arm points that far
    counter-clockwise from the "straight" arm) and has priority."""

    approach_length: float = 50.0  # [m] the ego's arm
    arm_length: float = 50.0  # [m] the other three arms
    minor_lanes: int = 1  # per direction
    main_lanes: int = 1  # per direction
    crossing_angle: float = math.pi / 2  # [rad]
    corner_radius: float = 10.0  # [m]
    lane_width: float = 3.5  # [m]
    speed_limit: float = 30 / 3.6  # [m/s] minor road
    main_speed_limit: float = 50 / 3.6  # [m/s]
    turn: str = "straight"  # the route's movement: the chain leaves by that arm

    def __post_init__(self) -> None:
        _common(self)
        check_number("main_speed_limit", self.main_speed_limit, *SPEED_LIMIT_RANGE)
        check_number("approach_length", self.approach_length, 25.0, 1000.0)
        check_number("arm_length", self.arm_length, 15.0, 1000.0)
        check_int("minor_lanes", self.minor_lanes, 1, MAX_LANES)
        check_int("main_lanes", self.main_lanes, 1, MAX_LANES)
        check_number("crossing_angle", self.crossing_angle, math.radians(50), math.radians(130))
        check_number("corner_radius", self.corner_radius, 3.0, 50.0)
        check("turn", self.turn, self.turn in TURNS, f"one of {TURNS}")


@dataclass(frozen=True)
class MergeParams(_FromDict):
    """A two-way approach road (one lane each way) meets a main road from its right at `merge_angle`:
    the ego's lane bends right through an arc of `slip_radius` into an acceleration lane of
    `accel_length` beside the main road, which tapers into the main road's rightmost lane. Main-road
    traffic may turn right into the approach's other lane where that turn fits (steep merge angles)."""

    approach_length: float = 40.0  # [m]
    merge_angle: float = math.radians(60)  # [rad] between the approach and the main road
    slip_radius: float = 20.0  # [m]
    main_before: float = 70.0  # [m] main road before the acceleration lane
    accel_length: float = 60.0  # [m]
    taper_length: float = 30.0  # [m]
    exit_length: float = 50.0  # [m] main road after the taper
    main_lanes: int = 1  # in the merging direction
    main_opposite_lanes: int = 1
    lane_width: float = 3.5  # [m]
    speed_limit: float = 30 / 3.6  # [m/s] approach
    main_speed_limit: float = 50 / 3.6  # [m/s]

    def __post_init__(self) -> None:
        _common(self)
        check_number("main_speed_limit", self.main_speed_limit, *SPEED_LIMIT_RANGE)
        check_number("approach_length", self.approach_length, 25.0, 1000.0)
        check_number("merge_angle", self.merge_angle, math.radians(20), math.radians(90))
        # The bend lifts the approach's end by slip_radius * (1 - cos(merge_angle)); its other lane, one lane
        # width to the left, must stay clear of the main road.
        lift = 1.0 - math.cos(self.merge_angle)
        least = (self.lane_width * math.cos(self.merge_angle) + APPROACH_CLEARANCE) / lift
        check_number("slip_radius", self.slip_radius, max(8.0, math.ceil(least * 10) / 10), 200.0)
        check_number("main_before", self.main_before, 10.0, 1000.0)
        check_number("accel_length", self.accel_length, 10.0, 1000.0)
        check_number("taper_length", self.taper_length, 4.0 * self.lane_width, 500.0)
        check_number("exit_length", self.exit_length, 5.0, 1000.0)
        check_int("main_lanes", self.main_lanes, 1, MAX_LANES)
        check_int("main_opposite_lanes", self.main_opposite_lanes, 0, MAX_LANES)
