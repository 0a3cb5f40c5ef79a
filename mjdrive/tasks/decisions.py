"""The decision action set of the urban tasks (study 002 §5.1.3, task keyword `decisions=True`): one env step is
one decision period; underneath, the operative level (`mjdrive.control.operative`) drives the car at the
control rate from the ground truth this module reads.

Actions by task (`ACTIONS`): the lane-change scenario's keep / left / right, the other scenarios' drive / stop,
and on the concatenated route all four (drive, stop, left, right: "keep" is "drive"). Inside a scenario an action
of another scenario's set does what its default does (drive, keep); outside every scenario the level follows
the path whatever the action ("Follow Path", §4.2).

Ground truth each control period (`RouteTraffic.situation`): the car's route coordinates, the stop point of
the active scenario (the next give-way line of the conflict zones on the route, the lines traffic stops at),
the leaders (road users going the route's way whose footprint overlaps the band of the lane the car is in, or
moves to, ahead of it, or will within CUT_IN_TIME; their speed along the route and its change since the last
period; at merges, the vehicle traffic's zipper puts ahead of the ego), the nearest road user crossing a band
(a point to stop before, not a leader to follow), whether the right-of-way rules would have it wait at the
stop point now (`Traffic.give_way`: the car then approaches it slowly, whatever the decision), the lanes a
lane change can reach now (there, going on, and with a gap that takes the car: `RouteTraffic.lanes_open`) and
the end of a neighbour lane the car is in.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from mjdrive.control.mpc import Leader
from mjdrive.control.operative import DRIVE, LEFT, RIGHT, STOP, Situation
from mjdrive.roads.roadmap import RoadMap
from mjdrive.roads.route_frame import RouteFrame
from mjdrive.traffic import EgoState, Traffic
from mjdrive.traffic.params import PATH

FOLLOW, LANE_CHANGE = "follow", "lane_change"
ACTIONS = {"roundabout": ("drive", "stop"), "crossroad": ("drive", "stop"), "merge": ("drive", "stop"),
           "lane_change": ("keep", "left", "right"), "concatenated": ("drive", "stop", "left", "right"),
           "opendrive": ("drive", "stop", "left", "right")}
SCENARIO_ACTIONS = {LANE_CHANGE: {"keep": DRIVE, "drive": DRIVE, "left": LEFT, "right": RIGHT},
                    "roundabout": {"drive": DRIVE, "stop": STOP}, "crossroad": {"drive": DRIVE, "stop": STOP},
                    "merge": {"drive": DRIVE, "stop": STOP}}
BAND_MARGIN = 0.4  # [m] beyond the ego's half width: a road user this close to the lane's band is in it
LOOK_AHEAD = 100.0  # [m] leaders farther ahead along the route are left out
LOOK_BEHIND = 60.0  # [m] road users farther behind are left out (a lane change's gap acceptance looks this far)
MAX_LEADER_ACCEL = 8.0  # [m/s^2] bound on a leader's measured acceleration (a respawned slot jumps)
LANE_CHANGE_ROOM = 70.0  # [m] a lane change starts only where the lane it leads to goes on this far
MERGE_RANGE = 60.0  # [m] the zipper's leader (and whether to yield) is asked for within this distance
SAME_LINE = 1.5  # [m] traffic's wait point this close to the scenario's stop point is that point
CUT_IN_TIME = 1.5  # [s] a road user moving across into the ego's lane within this time is a leader already
ALIGNED = 0.5  # cos of the angle to the route above which a road user goes the route's way (else it crosses)
OVERLAP = 1.0  # [m] a road user whose centre is no more than this behind the ego's front is ahead of it
# Gap acceptance of a lane change (`RouteTraffic.lane_free`)
LANE_GAP = 4.0  # [m] bumper to bumper, at rest
LANE_HEADWAY = 0.6  # [s]
SAFE_DECEL = 2.0  # [m/s^2] the most the ego or its new follower has to brake to match speeds
CROSSING_TIME = 2.0  # [s] the follower closes in this long before the ego is in its lane
# The overtaking rule of the privileged drivers (`RouteTraffic.overtaking`)
OVERTAKE_RANGE = 40.0  # [m] a leader nearer than this that is slower than the ego wants to drive is overtaken
OVERTAKE_MARGIN = 2.0  # [m/s] ... by at least this much
OVERTAKE_ROOM = 120.0  # [m] ... where the left lane goes on at least this far (out, past, and back)
RETURN_MARGIN = 25.0  # [m] ... and the ego reaches a gap to come back into this far before the left lane ends
RETURN_RANGE = 40.0  # [m] this close to the left lane's end the ego comes back at the first gap, slow road users or not
STANDING_ROOM = 1.0  # [m] ... where a road user standing behind (slower than STANDING_SPEED) is far enough behind
STANDING_SPEED = 0.5  # [m/s]


class Seen(NamedTuple):
    """The road users near the ego, projected onto the route (`RouteTraffic.observe`), each (K,)."""

    ahead: np.ndarray  # [m] the ego's front bumper to their rear (along the route)
    centre: np.ndarray  # [m] the ego's front bumper to their centre
    behind: np.ndarray  # [m] their front to the ego's rear
    offset: np.ndarray  # [m] their centre's offset from the route (left > 0)
    half_lat: np.ndarray  # [m] half their footprint's extent across the route
    along: np.ndarray  # [m/s] their speed along the route
    accel: np.ndarray  # [m/s^2] its change since the last control period
    across: np.ndarray  # [m/s] their speed across the route (left > 0)
    aligned: np.ndarray  # bool: going the route's way
    indicator: np.ndarray  # the lane-change indicator they show: +1 left, -1 right, 0 none


def operative_decision(action: str, scenario: str) -> str:
    """The operative level's decision for the named action in the active scenario (see the module docstring)."""
    return SCENARIO_ACTIONS.get(scenario, {}).get(action, DRIVE)


class RouteTraffic:
    """Reads the ground truth of the operative level for an ego on a route: the route's lanes and give-way
    lines (built once per task) and the road users each control period."""

    def __init__(self, road_map: RoadMap, route: tuple[int, ...], route_starts: np.ndarray, frame: RouteFrame,
                 route_heading, scenario_at, give_way_lines: tuple[np.ndarray, np.ndarray], merges: np.ndarray,
                 length: float, width: float, dt: float):
        """`route_heading(s)`: the route's heading [rad] at arc lengths s; `scenario_at(s)`: the tactical
        trajectory's scenario; `give_way_lines`: (route s [m] of each give-way line the ego meets, its scenario);
        `merges`: route s [m] of the merge points on the route; `length`, `width` [m] of the ego; dt [s] the control
        period."""
        self.road_map, self.route, self.frame, self.merges = road_map, route, frame, merges
        self.starts = route_starts
        self.heading, self.scenario_at = route_heading, scenario_at
        self.lines, self.line_scenario = give_way_lines
        self.half_length, self.half_width, self.dt = 0.5 * length, 0.5 * width, dt
        lanes = road_map.lanes
        self.ends = np.array([self.starts[k] + lanes[lane].length for k, lane in enumerate(route)])  # [m]
        self.lane_width = np.array([lanes[lane].width for lane in route])  # [m]
        self.index = 0  # the route lane of the last `situation`
        self.left = [road_map.left_neighbour[lane] for lane in route]
        self.right = [road_map.right_neighbour[lane] for lane in route]
        self.reset(0)

    def reset(self, n: int) -> None:
        """Forget the road users' speeds (n slots)."""
        self._speed = np.zeros(n)  # [m/s] along the route at the last period
        self._generation = np.full(n, -1, dtype=np.int64)

    def route_index(self, s: float) -> int:
        """The index of the route lane at arc length s [m]."""
        return int(min(max(np.searchsorted(self.starts, s, side="right") - 1, 0), len(self.route) - 1))

    def stop_line(self, s: float, scenario: str) -> float | None:
        """[m] from the front bumper to the next give-way line of `scenario` still ahead (a line passed by less
        than 0.5 m counts as reached: 0); None if none."""
        front = s + self.half_length
        ahead = np.flatnonzero((self.lines > front - 0.5) & (self.line_scenario == scenario))
        return max(float(self.lines[ahead[0]]) - front, 0.0) if len(ahead) else None

    def neighbour_path(self, s: float, side: int) -> tuple[np.ndarray, float] | None:
        """(lane path, s along its first lane [m]) of the neighbour lane (side +1 left, -1 right) of the route lane
        at s, for traffic's view of an ego driving there; None where there is none."""
        k = self.route_index(s)
        lane = (self.left if side > 0 else self.right)[k]
        if lane is None:
            return None
        path = [lane]
        while len(path) < PATH and self.road_map.successors[path[-1]]:
            path.append(self.road_map.successors[path[-1]][0])
        return np.array(path, dtype=np.int64), float(s - self.starts[k])

    def observe(self, s: float, traffic: Traffic, track: bool = True) -> None:
        """Project the road users near the ego (at route position s [m]) onto the route: their route position,
        offset, footprint extents along and across the route, speed along it and its change since the last
        period (`track`: this is the period's observation, whose speeds the next one's changes start from; a
        look in between, e.g. by a policy, passes False)."""
        present = traffic.present
        n = len(present)
        if len(self._speed) != n:
            self.reset(n)
        near = np.flatnonzero(present)
        route_s, offset = self.frame.project(traffic.positions()[near], s - LOOK_BEHIND, s + LOOK_AHEAD)
        rel_yaw = traffic.yaws()[near] - self.heading(route_s)
        c, sn = np.abs(np.cos(rel_yaw)), np.abs(np.sin(rel_yaw))
        half = traffic.half_size[near]
        along = traffic.speeds()[near] * np.cos(rel_yaw)  # [m/s]
        generation = traffic.generation[near]
        same = generation == self._generation[near]
        accel = np.clip(np.where(same, (along - self._speed[near]) / self.dt, 0.0), -MAX_LEADER_ACCEL,
                        MAX_LEADER_ACCEL)
        if track:
            self._speed[near], self._generation[near] = along, generation
        # beyond the window the projection sits on its end, its offset meaningless: those road users are left out
        k = np.flatnonzero((route_s > s - LOOK_BEHIND) & (route_s < s + LOOK_AHEAD))
        route_s, offset, along, accel, c, sn, half = route_s[k], offset[k], along[k], accel[k], c[k], sn[k], half[k]
        half_long = c * half[:, 0] + sn * half[:, 1]  # [m] the footprint's extent along the route
        front = s + self.half_length
        self.seen = Seen(route_s - half_long - front, route_s - front, s - self.half_length - (route_s + half_long),
                         offset, sn * half[:, 0] + c * half[:, 1], along, accel,
                         traffic.speeds()[near[k]] * np.sin(rel_yaw[k]), np.cos(rel_yaw[k]) > ALIGNED,
                         traffic.indicators()[near[k]])

    def in_band(self, centre: float, ahead_time: float = 0.0) -> np.ndarray:
        """Which of the observed road users overlap the band of the lane centred `centre` [m] from the route, now
        (or `ahead_time` [s] from now, moving across at their present lateral speed)."""
        seen = self.seen
        offset = seen.offset + seen.across * ahead_time
        return np.abs(offset - centre) < seen.half_lat + self.half_width + BAND_MARGIN

    def leaders(self, centres: tuple[float, ...]) -> tuple[list[Leader], float | None]:
        """(the nearest road user ahead going the route's way in the band of each lane centred `centres` [m] from
        the route, now, or moving into it within CUT_IN_TIME, or signalling a lane change into it; the gap [m] to
        the nearest one crossing or coming the other way in a band now, None if none)."""
        seen = self.seen
        near = (seen.centre > -OVERLAP) & (seen.ahead < LOOK_AHEAD)
        out, crossing = [], None
        target = seen.offset + seen.indicator * self.lane_width[self.index]  # where a signalled change goes
        for centre in dict.fromkeys(centres):  # each lane once
            now = self.in_band(centre)
            signalled = (seen.indicator != 0) & (np.abs(target - centre) < seen.half_lat + self.half_width)
            coming = self.in_band(centre, CUT_IN_TIME) | signalled
            inside = near & seen.aligned & (now | coming)
            if inside.any():
                k = np.flatnonzero(inside)[np.argmin(seen.ahead[inside])]
                out.append(Leader(max(float(seen.ahead[k]), 0.0), max(float(seen.along[k]), 0.0),
                                  float(seen.accel[k]), alongside=bool(seen.ahead[k] <= 0.0)))
            across = near & ~seen.aligned & now
            if across.any():
                gap = max(float(seen.ahead[across].min()), 0.0)
                crossing = gap if crossing is None else min(crossing, gap)
        return out, crossing

    def lane_gaps(self, centre: float) -> tuple[float, float, float, float]:
        """(gap ahead [m], its speed [m/s], gap behind [m], its speed [m/s]) of the nearest observed road users
        before and after the ego in the band of the lane centred `centre` [m] (the one after going the route's way);
        a road user beside the ego has gap 0 both ways; inf and 0 where there is none."""
        ahead, behind, along = self.seen.ahead, self.seen.behind, self.seen.along
        band = self.in_band(centre)
        beside = band & (ahead <= 0.0) & (behind <= 0.0)
        if beside.any():
            return 0.0, float(along[beside][0]), 0.0, float(along[beside][0])
        front, back = band & (ahead > 0.0), band & self.seen.aligned & (behind > 0.0)
        k_front = np.flatnonzero(front)[np.argmin(ahead[front])] if front.any() else None
        k_back = np.flatnonzero(back)[np.argmin(behind[back])] if back.any() else None
        return (float(ahead[k_front]) if k_front is not None else math.inf,
                float(along[k_front]) if k_front is not None else 0.0,
                float(behind[k_back]) if k_back is not None else math.inf,
                float(along[k_back]) if k_back is not None else 0.0)

    def rear_axle(self, s: float, x: float, y: float, yaw: float, wheelbase: float) -> tuple[float, float, float]:
        """(s [m], offset [m], heading error [rad]) of the rear axle's centre on the route, for a car at (x, y) [m]
        heading yaw [rad] whose centre is at s [m] along it."""
        half = 0.5 * wheelbase
        point = np.array([[x - half * math.cos(yaw), y - half * math.sin(yaw)]])
        rear_s, rear_d = self.frame.project(point, s - wheelbase - 1.0, s + 1.0)
        error = (yaw - float(self.heading(rear_s[0])) + math.pi) % (2 * math.pi) - math.pi
        return float(rear_s[0]), float(rear_d[0]), error

    def lane_free(self, centre: float, speed: float, zipper: bool = False) -> bool:
        """Whether the lane centred `centre` [m] from the route takes the ego at `speed` [m/s] now (gap acceptance
        of a lane change, MOBIL's safety criterion with a headway): the ego can keep LANE_GAP plus LANE_HEADWAY of
        its speed behind the road user ahead braking at most SAFE_DECEL to its speed, and the road user behind
        likewise behind the ego, after closing in for CROSSING_TIME while the ego moves across. zipper (where the
        ego's lane ends): a road user standing behind, letting the ego in, needs only STANDING_ROOM."""
        ahead, v_ahead, behind, v_behind = self.lane_gaps(centre)
        if zipper and v_behind < STANDING_SPEED and ahead > 0.0:
            behind = math.inf if behind >= STANDING_ROOM else behind
        closing = max(v_behind - speed, 0.0)  # [m/s]
        front = LANE_GAP + LANE_HEADWAY * speed + max(speed - v_ahead, 0.0) ** 2 / (2.0 * SAFE_DECEL)
        rear = LANE_GAP + LANE_HEADWAY * v_behind + closing * CROSSING_TIME + closing**2 / (2.0 * SAFE_DECEL)
        return ahead >= front and behind >= rear

    def return_gap(self, centre: float, speed: float) -> tuple[float, float]:
        """(distance [m] from the ego's front to the first gap ahead in the band of the lane centred `centre` [m]
        long enough to come back into at `speed` [m/s] (the ego's length and LANE_GAP plus LANE_HEADWAY of the
        speed each side), the speed [m/s] of the road user before it (0: none)); inf if the observed stretch has
        none (LOOK_AHEAD)."""
        seen = self.seen
        ahead = self.in_band(centre) & seen.aligned & (seen.ahead > 0.0)
        need = 2.0 * (self.half_length + LANE_GAP + LANE_HEADWAY * speed)
        order = np.flatnonzero(ahead)[np.argsort(seen.ahead[ahead], kind="stable")]
        if not len(order):
            return 0.0, 0.0
        for i, j in zip(order, [*order[1:], -1], strict=True):
            front = 2.0 * float(seen.centre[i]) - float(seen.ahead[i])  # [m] its front bumper
            space = (float(seen.ahead[j]) if j >= 0 else LOOK_AHEAD) - front
            if space >= need:
                return front, max(float(seen.along[i]), 0.0)
        return math.inf, 0.0

    def overtaking(self, s: float, speed: float, wanted: float, target: float,
                   margin: float = OVERTAKE_MARGIN) -> str:
        """The privileged drivers' lane-change decision on a two-lane road ("left", "right" or "keep") for the ego at
        s [m] going `speed` [m/s] wanting `wanted` [m/s], in (or moving to) the lane centred `target` [m] from the
        route: overtake a road user slower than it wants (by `margin` [m/s], within OVERTAKE_RANGE) when the left
        lane is faster, free now (`lane_free`) and goes on far enough to pass and reach a gap to come back into
        before it ends (`return_gap`); come back once the route's lane has no slow road user near ahead and room.
        Needs `observe` first."""
        width = float(self.lane_width[self.route_index(s)])
        ahead, v_ahead, _, _ = self.lane_gaps(0.0)
        slow = ahead < OVERTAKE_RANGE and v_ahead < wanted - margin
        if target != 0.0:  # in the left lane: back once past the slow road users (or where it ends), at a gap
            ending = self.lane_length_left(s) < RETURN_RANGE
            return "right" if (ending or not slow) and self.lane_free(0.0, speed, ending) else "keep"
        left_ahead, v_left, _, _ = self.lane_gaps(width)
        faster = left_ahead > OVERTAKE_RANGE or v_left > v_ahead + margin
        left_end = self.lane_length_left(s)
        if not (slow and faster and left_end >= OVERTAKE_ROOM and self.lane_free(width, speed)):
            return "keep"
        gap, v_gap = self.return_gap(0.0, v_ahead)
        v_pass = wanted if left_ahead > OVERTAKE_RANGE else min(wanted, v_left)  # [m/s] in the left lane
        reach = gap * v_pass / max(v_pass - v_gap, 0.5)  # [m] driven until the gap is beside the ego
        return "left" if reach + RETURN_MARGIN <= left_end else "keep"

    def lanes_open(self, s: float, speed: float, target: float, decision: str | None = None) -> tuple[bool, bool, bool]:
        """(a lane change to the left may start now, one to the right may, the route's own lane takes the car back
        now) for the ego at s [m] going `speed` [m/s] in (or moving to) the lane centred `target` [m] from the route.
        A lane change starts where the lane it leads to is there, goes on LANE_CHANGE_ROOM, and takes the car now
        (`lane_free`); back to the route's lane, near the end of the lane the car is in, as a zipper. `decision`
        (the operative level's): only the side it asks for is checked (the other is False); None: both. Needs
        `observe` first."""
        k = self.route_index(s)
        if target != 0.0:
            ending = float(self.ends[k]) - (s + self.half_length) < RETURN_RANGE
            back_free = self.lane_free(0.0, speed, zipper=ending)
            return False, target > 0.0 and back_free, back_free
        width = float(self.lane_width[k])
        room = self.ends[k] - s > LANE_CHANGE_ROOM
        left = decision in (None, LEFT) and self.left[k] is not None and room and self.lane_free(width, speed)
        right = decision in (None, RIGHT) and self.right[k] is not None and room and self.lane_free(-width, speed)
        return left, right, True

    def lane_distance(self, s: float, offset: float) -> float:
        """[m] from a point `offset` [m] left of the route at s [m] to the nearer centre line of the route lane
        there and its same-direction neighbour on that side (a car overtaking is on the road)."""
        k = self.route_index(s)
        neighbour = (self.left if offset > 0 else self.right)[k]
        distance = abs(offset)
        return distance if neighbour is None else min(distance, abs(distance - float(self.lane_width[k])))

    def lane_length_left(self, s: float) -> float:
        """[m] from arc length s to where the route lane there, and its neighbours, end."""
        return float(self.ends[self.route_index(s)] - s)

    def situation(self, s: float, pose: tuple[float, float, float], speed: float, decision: str,
                  lanes: tuple[float, ...], traffic: Traffic, ego: EgoState, wheelbase: float) -> Situation:
        """The ground truth of this control period for the operative level: the car's centre at s [m] along the
        route, its pose (x, y, yaw) [m, m, rad]; `lanes`: the centre offsets [m] of the lane the car is in and,
        during a lane change, the one it moves to, the last its target."""
        self.index = k = self.route_index(s)
        self.observe(s, traffic)
        rear_s, rear_lateral, heading_error = self.rear_axle(s, *pose, wheelbase)
        scenario = self.scenario_at(s)
        active = scenario != FOLLOW
        leaders, crossing = self.leaders(lanes)
        front = s + self.half_length
        stop = self.stop_line(s, scenario) if active else None
        merging = np.any((self.merges > front - self.half_length) & (self.merges < front + MERGE_RANGE))
        near_line = stop is not None and stop < MERGE_RANGE
        yielding = False  # the rules would have the ego wait at the stop line now
        if active and (merging or near_line) and ego.path is not None:
            asked = traffic.give_way(ego)
            if math.isfinite(asked.leader_gap):  # merges: the zipper's leader
                leaders.append(Leader(max(asked.leader_gap, 0.0), max(asked.leader_speed, 0.0),
                                      alongside=asked.leader_gap <= 0.0))
            yielding = near_line and abs(asked.stop - stop) < SAME_LINE
        target = lanes[-1]
        lane_end = float(self.ends[k]) - (s + self.half_length) if target != 0.0 else None  # never past its end
        applied = operative_decision(decision, scenario)
        left, right, back_free = self.lanes_open(s, speed, target, applied)
        return Situation(s, rear_s, rear_lateral, heading_error, speed, applied,
                         active, stop, tuple(leaders), float(self.lane_width[k]), left, right, lane_end, crossing,
                         back_free, yielding)
