"""Junction control: give-way (the conflict zones' right of way alone), stop signs and traffic lights at a map's
junction entries (`RoadMap.junction_entries`: the lanes that end at a junction's mouth, each in the main-road or
the minor-road group).

- stop signs on the minor road: a vehicle comes to rest (slower than HALT_SPEED) within HALT_RANGE of the line
  at its lane's end, then gives way as at a give-way line;
- traffic lights: the main road green, amber, all red, then the minor road green, amber, all red (`SignalTiming`);
  red stops a vehicle at the line unless it is past it, amber unless it could not stop braking at AMBER_DECEL;
  within a green, the conflict zones' right of way still applies (left turns yield to oncoming traffic).
- the map's own (`RoadMap.entry_signs`, e.g. an OpenDRIVE file's signals): a stop sign or traffic lights at the
  entries the map puts them at, give-way at the others.

The rules are vectorised over vehicles and entries (a junction has a handful of entries); traffic folds the stop
gaps into its IDM like every other stop line and counts the violations of its own vehicles.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from mjdrive.config import Config, param
from mjdrive.roads.roadmap import MAIN_ROAD, MINOR_ROAD, RoadMap

CONTROLS = ("give_way", "stop", "lights")  # junction control kinds (the ones "random" draws from)
GIVE_WAY, STOP_SIGNS, LIGHTS = range(3)
MAP = 3  # the map's own signs and lights at each entry (`RoadMap.entry_signs`)
KEYWORDS = (*CONTROLS, "map")  # what `Traffic.set_junction_control` takes, indexed by the constants above
SIGN_KINDS = {"stop": STOP_SIGNS, "lights": LIGHTS}  # `RoadMap.entry_signs` values
GREEN, AMBER, RED, STOP_SIGN = range(4)  # what an entry shows now
STATE_NAMES = ("green", "amber", "red", "stop")
STOP_MARGIN = 1.0  # [m] the line: this far before the end of the entry lane (the give-way line's place)
COMMITTED = 0.5  # [m] a front bumper this far past the line goes on
HALT_SPEED = 0.3  # [m/s] slower than this is at rest ...
HALT_RANGE = 5.0  # [m] ... at a stop sign when the front bumper is this close to the line
AMBER_DECEL = 3.0  # [m/s^2] at amber, a vehicle stops if it can braking at most this


@dataclass(frozen=True)
class SignalTiming(Config):
    """A signalised junction's cycle: main-road green, amber, all red, minor-road green, amber, all red."""

    green_main: float = param(20.0, "main road green", "s", ge=3.0, le=300.0)
    green_minor: float = param(12.0, "minor road green", "s", ge=3.0, le=300.0)
    amber: float = param(3.0, "amber after each green", "s", ge=1.0, le=10.0)
    all_red: float = param(2.0, "all red after each amber (clearance)", "s", ge=0.0, le=20.0)

    @property
    def cycle(self) -> float:
        """[s] one whole cycle."""
        return self.green_main + self.green_minor + 2 * (self.amber + self.all_red)


class Junctions(NamedTuple):
    """A map's junction entries (E,) and the control in force."""

    lane: np.ndarray  # (E,) entry lane ids
    group: np.ndarray  # (E,) MAIN_ROAD or MINOR_ROAD
    line: np.ndarray  # (E,) [m] the stop line along the lane (front bumper)
    sign: np.ndarray  # (E,) what the map puts at each entry: GIVE_WAY, STOP_SIGNS or LIGHTS (used under MAP)
    control: int  # GIVE_WAY, STOP_SIGNS, LIGHTS or MAP
    kind: np.ndarray  # (E,) the control in force at each entry: GIVE_WAY, STOP_SIGNS or LIGHTS (`controlled`)
    timing: SignalTiming
    offset: float  # [s] where in its cycle the signal starts

    @classmethod
    def of(cls, road_map: RoadMap) -> Junctions:
        """The entries of `road_map`, under give-way."""
        rows = np.array(road_map.junction_entries, dtype=np.int64).reshape(-1, 2)
        lengths = np.array([road_map.lanes[int(i)].length for i in rows[:, 0]], dtype=float)
        sign = np.array([SIGN_KINDS.get(road_map.entry_signs.get(int(i), ""), GIVE_WAY) for i in rows[:, 0]],
                        dtype=np.int64)
        return cls(rows[:, 0].copy(), rows[:, 1].copy(), lengths - STOP_MARGIN, sign, GIVE_WAY,
                   np.full(len(rows), GIVE_WAY, dtype=np.int64), SignalTiming(), 0.0)

    def controlled(self, control: int, timing: SignalTiming | None = None, offset: float = 0.0) -> Junctions:
        """These entries under `control` (GIVE_WAY, STOP_SIGNS: on the minor road's entries, LIGHTS, or MAP: the
        map's own `sign`), the lights on `timing` starting `offset` [s] into its cycle."""
        kind = (self.sign if control == MAP else np.where(self.group == MINOR_ROAD, STOP_SIGNS, GIVE_WAY)
                if control == STOP_SIGNS else np.full(len(self.lane), control, dtype=np.int64))
        return self._replace(control=control, kind=kind, timing=timing or SignalTiming(), offset=float(offset))

    @property
    def active(self) -> bool:
        """Whether anything beyond give-way is in force."""
        return self.control != GIVE_WAY and bool(self.kind.any())  # GIVE_WAY is 0


def entry_states(junctions: Junctions, time: float) -> np.ndarray:
    """(E,) what each entry shows at `time` [s]: GREEN (also under give-way), AMBER, RED or STOP_SIGN."""
    out = np.full(len(junctions.lane), GREEN, dtype=np.int64)
    if junctions.control == GIVE_WAY:
        return out
    kinds = junctions.kind
    out[kinds == STOP_SIGNS] = STOP_SIGN
    t = junctions.timing
    u = (time + junctions.offset) % t.cycle  # [s] into the cycle
    starts = {MAIN_ROAD: 0.0, MINOR_ROAD: t.green_main + t.amber + t.all_red}
    greens = {MAIN_ROAD: t.green_main, MINOR_ROAD: t.green_minor}
    for group in (MAIN_ROAD, MINOR_ROAD):
        into = (u - starts[group]) % t.cycle  # [s] since this group's green began
        state = GREEN if into < greens[group] else AMBER if into < greens[group] + t.amber else RED
        out[(junctions.group == group) & (kinds == LIGHTS)] = state
    return out


def line_gaps(junctions: Junctions, offset: np.ndarray, s: np.ndarray, length: np.ndarray) -> np.ndarray:
    """(F, E) [m] from each follower's front bumper to each entry's line along its path (inf: not on its path);
    offset (F, lanes): `Agents.offset` rows (a lane's start relative to the follower's lane), s [m], length [m]."""
    front = s + length / 2
    return offset[:, junctions.lane] + junctions.line[None, :] - front[:, None]


def at_rest_at_line(gap, speed):
    """Whether a vehicle whose front bumper is `gap` [m] before a line (negative: past it) at `speed` [m/s] has come
    to rest there (a stop sign's demand; scalars or arrays)."""
    return (gap > -COMMITTED) & (gap < HALT_RANGE) & (speed < HALT_SPEED)


def violation(state, halted):
    """What crossing a line showing `state` is, for a vehicle that has (`halted`) or has not come to rest at it:
    "red_light", "stop_sign" or None (green, amber, a stop sign after stopping)."""
    if state == RED:
        return "red_light"
    if state == STOP_SIGN and not halted:
        return "stop_sign"
    return None


def halted_lanes(junctions: Junctions, states: np.ndarray, lane: np.ndarray, gaps: np.ndarray, speed: np.ndarray,
                 halted: np.ndarray) -> np.ndarray:
    """(F,) the stop-sign entry each follower has come to rest at (-1: none): kept while it is on that lane, set when
    it stands (speed [m/s] < HALT_SPEED) within HALT_RANGE of a stop sign's line on its current lane (`lane` (F,))."""
    out = np.where(lane == halted, halted, -1)
    here = (junctions.lane[None, :] == lane[:, None]) & (states[None, :] == STOP_SIGN)
    rested = (here & at_rest_at_line(gaps, speed[:, None])).any(axis=1)
    return np.where(rested, lane, out)


def stop_gaps(junctions: Junctions, states: np.ndarray, gaps: np.ndarray, speed: np.ndarray,
              halted: np.ndarray) -> np.ndarray:
    """(F,) [m] to the nearest line each follower must stop at now (inf: none): red; amber unless it could not stop
    braking at AMBER_DECEL; a stop sign it has not come to rest at (`halted`, per follower). Lines it is past by
    COMMITTED are behind it."""
    ahead = gaps > -COMMITTED
    v2 = (speed * speed)[:, None]
    must = ((states == RED)[None, :] | ((states == AMBER)[None, :] & (v2 < 2.0 * AMBER_DECEL * gaps))
            | ((states == STOP_SIGN)[None, :] & (halted[:, None] != junctions.lane[None, :])))
    return np.where(must & ahead, gaps, np.inf).min(axis=1, initial=np.inf)
