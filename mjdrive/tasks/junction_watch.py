"""The ego at the controlled junction entries on its route (`traffic.junction_control`): what the next one shows
(its observation), whether it came to rest at a stop sign, and the red light or stop sign it ran (which ends an
urban episode)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from mjdrive.traffic import junction_control as jc

FEATURES = 5  # stop sign, green, amber, red, distance to the line / distance scale (1: none ahead)
COLUMN = {jc.STOP_SIGN: 0, jc.GREEN: 1, jc.AMBER: 2, jc.RED: 3}  # the one-hot's column of what a line shows


class JunctionWatch:
    """The junction entries on a route, as route arc lengths of their lines."""

    def __init__(self, route: Sequence[int], route_starts: np.ndarray, junctions: jc.Junctions, half_length: float,
                 distance_scale: float):
        """route: lane ids; route_starts [m]: where each starts along the route; half_length [m]: the ego's front
        bumper ahead of its reference point; distance_scale [m]: the observation's distance normaliser."""
        lines, entries = [], []
        for k, lane in enumerate(route):
            hit = np.flatnonzero(junctions.lane == lane)
            if len(hit):
                lines.append(float(route_starts[k] + junctions.line[hit[0]]))
                entries.append(int(hit[0]))
        order = np.argsort(lines)
        self.line_s = np.asarray(lines, dtype=float)[order]  # [m] along the route
        self.entry = np.asarray(entries, dtype=np.int64)[order]  # rows of the junction entries
        self.half_length, self.distance_scale = half_length, distance_scale
        self.reset()

    def reset(self) -> None:
        """A new episode: every line ahead."""
        self.next = 0  # the first line not yet crossed
        self.halted = False  # the ego has come to rest at the next line (a stop sign)
        self.violation: str | None = None  # "red_light" or "stop_sign" once run

    def update(self, route_s: float, speed: float, states: np.ndarray) -> None:
        """The ego at route_s [m] and speed [m/s], the entries showing `states` (`Traffic.junction_state`): lines
        crossed since the last update are judged (`junction_control.violation`), a stop at the next one noted."""
        front = route_s + self.half_length
        while self.next < len(self.line_s) and front - self.line_s[self.next] > jc.COMMITTED:
            kind = jc.violation(states[self.entry[self.next]], self.halted)
            self.violation = self.violation or kind
            self.next += 1
            self.halted = False
        if self.next < len(self.line_s) and states[self.entry[self.next]] == jc.STOP_SIGN:
            self.halted |= bool(jc.at_rest_at_line(self.line_s[self.next] - front, speed))

    def features(self, route_s: float, states: np.ndarray, control: int) -> np.ndarray:
        """(FEATURES,) in [0, 1]: one-hot of what the next line shows (stop sign, green, amber, red; zeros under
        give-way or with none ahead), its distance from the front bumper / distance_scale (1: none ahead)."""
        out = np.zeros(FEATURES, np.float32)
        out[4] = 1.0
        if self.next < len(self.line_s):
            gap = self.line_s[self.next] - route_s - self.half_length
            out[4] = np.clip(gap / self.distance_scale, 0.0, 1.0)
            if control != jc.GIVE_WAY:
                out[COLUMN[int(states[self.entry[self.next]])]] = 1.0
        return out
