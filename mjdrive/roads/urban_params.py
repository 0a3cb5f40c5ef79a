"""Validated parameters of the urban road pieces (study 002), declared with `mjdrive.config` like the tasks'
keywords: a bad value raises ConfigError (a ValueError) naming the parameter, the value and what is
allowed; `from_dict` rejects unknown keys, lists the valid ones and suggests the closest.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

from mjdrive.config import Config, ConfigError, param
from mjdrive.roads.lane import Marking

LANE_WIDTH_RANGE = (2.5, 5.0)  # [m]
SPEED_LIMIT_RANGE = (1.0, 40.0)  # [m/s]
MAX_LANES = 4  # lanes per direction
TURNS = ("left", "straight", "right")
APPROACH_CLEARANCE = 0.5  # [m] between the merge approach's left edge and the main road's right edge


def check(name: str, value: Any, ok: bool, allowed: str) -> None:
    """Raise ConfigError("name=value: must be allowed") unless `ok` (checks across several parameters)."""
    if not ok:
        raise ConfigError(f"{name}={value!r}: must be {allowed}")


def check_number(name: str, value: Any, lo: float, hi: float = math.inf) -> None:
    """A finite real number in [lo, hi] (ranges that depend on other parameters)."""
    real = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
    check(name, value, real and lo <= value <= hi, f">= {lo:g} and <= {hi:g}")


def check_int(name: str, value: Any, lo: int, hi: int) -> None:
    """An int in [lo, hi] (ranges that depend on other parameters)."""
    ok = isinstance(value, int) and not isinstance(value, bool) and lo <= value <= hi
    check(name, value, ok, f"an integer in {lo}..{hi}")


def _lane_width(default: float = 3.5) -> Any:
    return param(default, "lane width", "m", ge=LANE_WIDTH_RANGE[0], le=LANE_WIDTH_RANGE[1])


def _speed_limit(default: float, doc: str = "speed limit") -> Any:
    return param(default, doc, "m/s", ge=SPEED_LIMIT_RANGE[0], le=SPEED_LIMIT_RANGE[1])


@dataclass(frozen=True)
class RoundaboutParams(Config):
    """`roads.roundabout` plus the ego's entry and exit arm (arm a points at angle 2*pi*a/arms)."""

    radius: float = param(14.0, "middle of the ring", "m", le=100.0)
    lanes: int = param(2, "ring lanes", ge=1, le=MAX_LANES)
    arms: int = param(4, "two-way arms", ge=3, le=8)
    arm_length: float = param(50.0, "length of each arm", "m", ge=25.0, le=1000.0)
    lane_width: float = param(3.5, "lane width (at least 3 m: an entering and a leaving car pass side by side on the "
                              "arm's curved connectors)", "m", ge=3.0, le=LANE_WIDTH_RANGE[1])
    speed_limit: float = _speed_limit(30 / 3.6)
    crosswalk_offset: float = param(6.0, "crosswalk from the arm's start", "m", ge=0.0)
    entry_arm: int = param(2, "the ego arrives on this arm", ge=0)
    exit_arm: int = param(0, "and leaves by this one", ge=0)

    def check(self) -> None:
        check_number("crosswalk_offset", self.crosswalk_offset, 0.0, self.arm_length - 3.0)
        check_int("entry_arm", self.entry_arm, 0, self.arms - 1)
        check_int("exit_arm", self.exit_arm, 0, self.arms - 1)
        # `roads.roundabout`: entries meet the outer ring lane at angle delta, which must clear the arm's lane
        delta = min(0.35, 0.3 * 2 * math.pi / self.arms)
        least = (self.lane_width / 2 + 0.5) / math.sin(delta) - (self.lanes - 1) * self.lane_width / 2
        check_number("radius", self.radius, math.ceil(max(least, 3.0 + self.lanes * self.lane_width / 2) * 10) / 10,
                     100.0)


@dataclass(frozen=True)
class OvertakingRoadParams(Config):
    """A straight two-way road whose middle section has `lanes` lanes in the ego's direction (BROKEN lines
    between them: overtaking on the left) and `opposite_lanes` the other way. It starts and ends with
    `entry_lanes` / `exit_lanes` lanes; the extra lanes open and close on the left over `taper_length`."""

    length: float = param(200.0, "middle section (all lanes)", "m", ge=20.0, le=5000.0)
    lanes: int = param(2, "lanes in the ego's direction", ge=1, le=MAX_LANES)
    opposite_lanes: int = param(1, "lanes the other way", ge=0, le=MAX_LANES)
    entry_lanes: int = param(1, "lanes where the road starts", ge=1, le=MAX_LANES)
    exit_lanes: int = param(1, "lanes where it ends", ge=1, le=MAX_LANES)
    taper_length: float = param(40.0, "where lanes open and close", "m", le=500.0)
    stub_length: float = param(10.0, "straight road before the opening and after the closing taper", "m",
                               ge=1.0, le=1000.0)
    lane_width: float = _lane_width()
    speed_limit: float = _speed_limit(50 / 3.6)
    centre_marking: Marking = param(Marking.SOLID, "between the two directions")

    def check(self) -> None:
        check_int("entry_lanes", self.entry_lanes, 1, self.lanes)
        check_int("exit_lanes", self.exit_lanes, 1, self.lanes)
        check_number("taper_length", self.taper_length, 4.0 * self.lane_width * (self.lanes - 1) + 5.0, 500.0)


@dataclass(frozen=True)
class CrossroadParams(Config):
    """A four-way crossroad without signals. The ego's approach and the arm straight across are the minor
    road (give-way lines); the main road crosses it at `crossing_angle` (its "left" arm points that far
    counter-clockwise from the "straight" arm) and has priority."""

    approach_length: float = param(50.0, "the ego's arm", "m", ge=25.0, le=1000.0)
    arm_length: float = param(50.0, "the other three arms", "m", ge=15.0, le=1000.0)
    minor_lanes: int = param(1, "minor road lanes per direction", ge=1, le=MAX_LANES)
    main_lanes: int = param(1, "main road lanes per direction", ge=1, le=MAX_LANES)
    crossing_angle: float = param(math.pi / 2, "main road's angle to the minor road", "rad",
                                  ge=math.radians(50), le=math.radians(130))
    corner_radius: float = param(10.0, "kerb radius at the corners", "m", ge=3.0, le=50.0)
    lane_width: float = _lane_width()
    speed_limit: float = _speed_limit(30 / 3.6, "minor road speed limit")
    main_speed_limit: float = _speed_limit(50 / 3.6, "main road speed limit")
    turn: str = param("straight", "the route's movement: the chain leaves by that arm", choices=TURNS)


@dataclass(frozen=True)
class MergeParams(Config):
    """A two-way approach road (one lane each way) meets a main road from its right at `merge_angle`:
    the ego's lane bends right through an arc of `slip_radius` into an acceleration lane of
    `accel_length` beside the main road, which tapers into the main road's rightmost lane. Main-road
    traffic may turn right into the approach's other lane where that turn fits (steep merge angles)."""

    approach_length: float = param(40.0, "approach road", "m", ge=25.0, le=1000.0)
    merge_angle: float = param(math.radians(60), "between the approach and the main road", "rad",
                               ge=math.radians(20), le=math.radians(90))
    slip_radius: float = param(20.0, "the bend into the acceleration lane", "m", le=200.0)
    main_before: float = param(70.0, "main road before the acceleration lane", "m", ge=10.0, le=1000.0)
    accel_length: float = param(60.0, "acceleration lane", "m", ge=10.0, le=1000.0)
    taper_length: float = param(30.0, "where the acceleration lane tapers into the main road", "m", le=500.0)
    exit_length: float = param(50.0, "main road after the taper", "m", ge=5.0, le=1000.0)
    main_lanes: int = param(1, "main road lanes in the merging direction", ge=1, le=MAX_LANES)
    main_opposite_lanes: int = param(1, "main road lanes the other way", ge=0, le=MAX_LANES)
    lane_width: float = _lane_width()
    speed_limit: float = _speed_limit(30 / 3.6, "approach speed limit")
    main_speed_limit: float = _speed_limit(50 / 3.6, "main road speed limit")

    def check(self) -> None:
        # The bend lifts the approach's end by slip_radius * (1 - cos(merge_angle)); its other lane, one lane
        # width to the left, must stay clear of the main road.
        lift = 1.0 - math.cos(self.merge_angle)
        least = (self.lane_width * math.cos(self.merge_angle) + APPROACH_CLEARANCE) / lift
        check_number("slip_radius", self.slip_radius, max(8.0, math.ceil(least * 10) / 10), 200.0)
        check_number("taper_length", self.taper_length, 4.0 * self.lane_width, 500.0)


PIECE_NAMES = ("roundabout", "road", "crossroad", "merge")  # the pieces of Fig. 8, in its order


@dataclass(frozen=True)
class UrbanMap(Config):
    """A study-002 map as data: the pieces in route order and each piece's parameters (pieces left out of
    `order` are not built; their parameters are still checked). Given to the urban tasks as `map=` (a dict of
    these keywords, or the path of a YAML or JSON file of them) and to `roads.concatenated`."""

    order: tuple[str, ...] | None = param(None, "pieces in route order, each at most once (None: the task's "
                                          "pieces; roads.concatenated: all four)", choices=PIECE_NAMES)
    roundabout: RoundaboutParams = param(RoundaboutParams(), "the roundabout (keywords of RoundaboutParams)")
    road: OvertakingRoadParams = param(OvertakingRoadParams(), "the two-lane road (keywords of "
                                       "OvertakingRoadParams)")
    crossroad: CrossroadParams = param(CrossroadParams(), "the crossroad (keywords of CrossroadParams)")
    merge: MergeParams = param(MergeParams(), "the merge (keywords of MergeParams)")
    lane_width: float | None = param(None, "every piece's lane width (pieces meet with equal lanes); None: each "
                                     "piece's own", "m", ge=LANE_WIDTH_RANGE[0], le=LANE_WIDTH_RANGE[1])

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.lane_width is None:
            return
        default = OvertakingRoadParams().lane_width
        for name in PIECE_NAMES:
            piece = getattr(self, name)
            check(f"{name}.lane_width", piece.lane_width, piece.lane_width in (default, self.lane_width),
                  f"the map's lane_width ({self.lane_width:g} m) or left out when the map sets it")
            if self.order is not None and name not in self.order:  # a piece left out of the map keeps its own
                continue
            try:
                object.__setattr__(self, name, dataclasses.replace(piece, lane_width=self.lane_width))
            except ConfigError as error:
                if self.order is not None:  # (order None: checked once the task's pieces are known)
                    raise ConfigError(f"lane_width={self.lane_width:g}: {name}.{error}") from None

    def pieces(self, default: tuple[str, ...] = PIECE_NAMES) -> tuple[str, ...]:
        """`order`, or `default` where it is None."""
        return default if self.order is None else self.order
