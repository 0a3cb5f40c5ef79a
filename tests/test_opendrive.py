"""OpenDRIVE import (`roads.opendrive`, pyxodr): lanes within 5 cm of the reader's own samples, reference lines
against the standard's formulas (line, arc, poly3), the lane graph and routes across a junction, the
`urban/opendrive` task with traffic and the autopilot, and bad files refused in one line."""

from __future__ import annotations

import io
import math
import os
import subprocess
import sys

import numpy as np
import pytest
from lxml import etree
from pyxodr.road_objects.network import RoadNetwork

from mjdrive.assets import MAPS_DIR
from mjdrive.config import ConfigError
from mjdrive.envs import make_env
from mjdrive.policies import make_policy
from mjdrive.roads import conflict_zones
from mjdrive.roads.conflicts import MERGE, TIE, YIELD_A, YIELD_B
from mjdrive.roads.geometry import wrap_angle
from mjdrive.roads.opendrive import _parse, longest_route, read_opendrive, route_between
from mjdrive.roads.roadmap import MAIN_ROAD, MINOR_ROAD
from mjdrive.traffic import junction_control as jc
from mjdrive.traffic import overlapping_pairs
from mjdrive.traffic.lanes import polyline_distance

ROAD = """<?xml version="1.0"?>
<OpenDRIVE><header revMajor="1" revMinor="5"/>
<road id="1" length="{length}" junction="-1"><type s="0" type="town"><speed max="40" unit="km/h"/></type>
<planView><geometry s="0" x="10" y="5" hdg="0.3" length="{length}">{geometry}</geometry></planView>
<lanes><laneSection s="0">
<left><lane id="1" type="driving" level="false"><width sOffset="0" a="3.0" b="0" c="0" d="0"/></lane></left>
<center><lane id="0" type="none" level="false"/></center>
<right><lane id="-1" type="driving" level="false"><width sOffset="0" a="3.0" b="0" c="0" d="0"/></lane></right>
</laneSection></lanes></road></OpenDRIVE>
"""


def _road(tmp_path, geometry: str, length: float):
    path = tmp_path / "road.xodr"
    path.write_text(ROAD.format(geometry=geometry, length=length))
    return read_opendrive(path)


def _local(xy: np.ndarray) -> np.ndarray:
    """World points into the road's start frame (x0 = 10, y0 = 5, heading 0.3)."""
    c, s = math.cos(0.3), math.sin(0.3)
    d = xy - np.array([10.0, 5.0])
    return np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])


def test_a_line_an_arc_and_a_poly3_against_the_standard(tmp_path):
    """The right lane's centre line is the reference line moved 1.5 m to the right: on a line, a circle of radius
    1/k + 1.5 about the arc's centre, and the curve v(u) = c u^2 + d u^3 moved along its normal (OpenDRIVE 1.6 §7)."""
    rm = _road(tmp_path, "<line/>", 50.0)
    right = _local(rm.lanes[rm.lane_id("road1/section0/lane-1")].centre)
    np.testing.assert_allclose(right[:, 1], -1.5, atol=1e-6)
    assert rm.lanes[0].speed_limit == pytest.approx(40 / 3.6) and rm.lanes[0].width == pytest.approx(3.0)
    k = 0.02
    rm = _road(tmp_path, f'<arc curvature="{k}"/>', 60.0)
    right = _local(rm.lanes[rm.lane_id("road1/section0/lane-1")].centre)
    np.testing.assert_allclose(np.hypot(right[:, 0], right[:, 1] - 1 / k), 1 / k + 1.5, atol=0.01)
    c, d = 0.004, -0.00005
    rm = _road(tmp_path, f'<poly3 a="0" b="0" c="{c}" d="{d}"/>', 40.0)
    left = _local(rm.lanes[rm.lane_id("road1/section0/lane1")].centre)  # runs against the reference line
    u = np.linspace(0.0, 38.0, 400)
    v = c * u**2 + d * u**3
    slope = 2 * c * u + 3 * d * u**2
    normal = np.column_stack([-slope, np.ones_like(u)]) / np.hypot(slope, 1.0)[:, None]
    expected = np.column_stack([u, v]) + 1.5 * normal
    assert polyline_distance(expected, left).max() < 0.05


@pytest.mark.parametrize("name", ["four_way", "multilane", "roundabout"])
def test_lanes_within_5_cm_of_the_readers_own_samples(name):
    """Every driving lane's centre line against pyxodr's lane centre sampled ten times finer (5 cm)."""
    path = MAPS_DIR / f"{name}.xodr"
    rm = read_opendrive(path)
    fine = RoadNetwork(io.BytesIO(etree.tostring(_parse(path))), resolution=0.05).get_roads()
    checked = 0
    for road in fine:
        for k, section in enumerate(road.lane_sections):
            for lane in section.lanes:
                if lane.type != "driving":
                    continue
                ours = rm.lanes[rm.lane_id(f"road{road.id}/section{k}/lane{lane.id}")].centre
                assert polyline_distance(lane.traffic_flow_line[:, :2], ours).max() < 0.05
                checked += 1
    assert checked == len(rm.lanes)


def test_the_junction_lane_graph_and_a_route_across_it():
    rm = read_opendrive(MAPS_DIR / "four_way.xodr")
    incoming = [i for i, lane in enumerate(rm.lanes) if not lane.in_junction and rm.successors[i]]
    assert len(incoming) == 4 and all(len(rm.successors[i]) == 3 for i in incoming)  # left, straight, right
    for i in incoming:
        for j in rm.successors[i]:
            assert rm.lanes[j].in_junction
            assert np.hypot(*(rm.lanes[j].centre[0] - rm.lanes[i].centre[-1])) < 0.05  # they meet
    assert len(rm.areas) == 1  # the junction's paved area
    west = rm.lanes[incoming[0]].centre[0]
    route = route_between(rm, west, (190.0, -1.75))
    assert rm.lanes[route[1]].in_junction and len(route) == 3
    assert np.hypot(*(rm.lanes[route[-1]].centre[-1] - (192.0, -1.75))) < 5.0  # it ends where asked
    zones = conflict_zones(rm)
    assert len(zones.on_route(rm, route)) > 0  # the route crosses the other movements
    with pytest.raises(ConfigError, match="does not lead to"):
        route_between(rm, (190.0, -1.75), west)  # from the end of a lane that leaves the map


def test_the_multilane_road_has_neighbours_and_a_road_link():
    rm = read_opendrive(MAPS_DIR / "multilane.xodr")
    right = rm.lane_id("road0/section0/lane-2")
    assert rm.left_neighbour[right] == rm.lane_id("road0/section0/lane-1")
    assert rm.successors[right] == [rm.lane_id("road1/section0/lane-2")]
    assert len(longest_route(rm)) == 2


def test_the_roundabout_ring_is_closed_and_every_arm_enters_and_leaves_it():
    rm = read_opendrive(MAPS_DIR / "roundabout.xodr")
    road = [int(lane.name.split("/")[0].removeprefix("road")) for lane in rm.lanes]  # OpenDRIVE road ids
    arcs = {i for i in range(len(rm.lanes)) if 10 <= road[i] < 14}  # the ring's arcs
    start = lane = rm.lane_id("road10/section0/lane-1")
    visited = []
    for _ in range(4):  # arc -> the way through the next junction -> the next arc
        through = [j for j in rm.successors[lane] if any(n in arcs for n in rm.successors[j])]
        assert len(through) == 1 and rm.lanes[through[0]].in_junction
        lane = rm.successors[through[0]][0]
        visited.append(lane)
    assert visited[-1] == start and set(visited) == arcs  # around the ring and back
    for k in range(4):
        entry = rm.lane_id(f"road2{k}/section0/lane1")  # arm k's inbound lane
        (connector,) = rm.successors[entry]
        assert rm.lanes[connector].in_junction and rm.successors[connector] == [rm.lane_id(f"road1{k}/section0/lane-1")]
        leaving = [j for j in rm.successors[rm.lane_id(f"road1{(k - 1) % 4}/section0/lane-1")]
                   if rm.successors[j] == [rm.lane_id(f"road2{k}/section0/lane-1")]]
        assert len(leaving) == 1  # the exit to arm k
    zones = conflict_zones(rm)
    assert len(zones) == 4 and (zones.kind == MERGE).all()  # each entry merges with the ring's way through
    entries = {rm.successors[rm.lane_id(f"road2{k}/section0/lane1")][0] for k in range(4)}
    assert set(zones.yielding_lane.tolist()) == entries  # the file ranks the ring over the arms


def test_the_autopilot_crosses_an_imported_junction_in_traffic(drive_episode):
    env = make_env("urban", "opendrive", opendrive="four_way")
    task = env.unwrapped.task
    assert task.urban.tactical.names == ("crossroad",) and task.traffic.nv >= 10
    info = drive_episode(env, make_policy("autopilot", env), seed=0)
    assert info["success"] and not info["collision"], info
    traffic = task.traffic
    overlaps = 0
    for _ in range(int(120.0 / traffic.config.substep)):  # two more minutes of its traffic alone
        traffic.advance(traffic.config.substep)
        present = traffic.present
        overlaps += len(overlapping_pairs(traffic.poses()[present], traffic.half_size[present])) > 0
    assert overlaps == 0 and traffic.stats["spawned"] > 0


def test_decisions_on_an_imported_map(drive_episode):
    env = make_env("urban", "opendrive", opendrive="multilane", decisions=True, time_limit=60.0)
    info = drive_episode(env, make_policy("rules", env), seed=0)
    assert info["success"], info


BAD_FILES = [
    ("missing.xodr", None, r"cannot read the file"),
    ("text.xodr", "not xml at all", r"not an XML file"),
    ("other.xodr", "<OpenSCENARIO/>", r"the root element is <OpenSCENARIO>, not <OpenDRIVE>"),
    ("empty.xodr", "<OpenDRIVE><header/></OpenDRIVE>", r"no <road> in the file"),
    ("nolanes.xodr", ROAD.format(geometry="<line/>", length=50.0).replace('type="driving"', 'type="sidewalk"'),
     r"no driving lane in the file"),
]


@pytest.mark.parametrize("name, text, message", BAD_FILES, ids=[b[0] for b in BAD_FILES])
def test_bad_opendrive_files_are_one_line(tmp_path, name, text, message):
    path = tmp_path / name
    if text is not None:
        path.write_text(text)
    with pytest.raises(ConfigError, match=message):
        make_env("urban", "opendrive", opendrive=str(path))


def test_the_cli_reports_a_bad_opendrive_file_in_one_line(tmp_path):
    path = tmp_path / "broken.xodr"
    path.write_text("<OpenDRIVE><road")
    result = subprocess.run([sys.executable, "-m", "mjdrive.cli", "run", "--task", "urban/opendrive", "--episodes",
                             "1", "--task-kwarg", f"opendrive={path}"], capture_output=True, text=True, timeout=120)
    lines = result.stderr.strip().splitlines()  # "building urban/opendrive ...", then the error
    assert result.returncode == 2 and "Traceback" not in result.stderr and "not an XML file" in lines[-1], lines
    with pytest.raises(ConfigError, match="only urban/opendrive takes it"):
        make_env("urban", "crossroad", opendrive="four_way")


def _ranked_four_way(tmp_path) -> str:
    """The shipped four-way junction with its roads ranked: 0 and 2 (east-west) the main road, 1 and 3 minor."""
    tree = etree.parse(str(MAPS_DIR / "four_way.xodr"))
    (junction,) = tree.getroot().iter("junction")
    for high in ("0", "2"):
        for low in ("1", "3"):
            etree.SubElement(junction, "priority", high=high, low=low)
    path = tmp_path / "ranked.xodr"
    tree.write(str(path))
    return str(path)


def _road_id(rm, lane: int) -> str:
    return rm.lanes[lane].name.split("/")[0].removeprefix("road")


def test_junction_priorities_rank_the_main_road_and_put_give_way_lines_on_the_minor_one(tmp_path):
    plain = read_opendrive(MAPS_DIR / "four_way.xodr")
    assert (conflict_zones(plain).who_yields == TIE).all() and not plain.give_way and not plain.junction_entries
    rm = read_opendrive(_ranked_four_way(tmp_path))
    incoming = [i for i, lane in enumerate(rm.lanes) if not lane.in_junction and rm.successors[i]]
    minor = [i for i in incoming if _road_id(rm, i) in ("1", "3")]
    assert sorted(rm.give_way) == sorted((i, rm.lanes[i].length) for i in minor)  # the line at the mouth
    assert sorted(rm.junction_entries) == sorted((i, MINOR_ROAD if i in minor else MAIN_ROAD) for i in incoming)
    zones = conflict_zones(rm)
    source = {j: _road_id(rm, rm.predecessors(j)[0]) for j, lane in enumerate(rm.lanes) if lane.in_junction}
    checked = 0
    for a, b, who in zip(zones.lane_a, zones.lane_b, zones.who_yields, strict=True):
        main_a, main_b = source[a] in ("0", "2"), source[b] in ("0", "2")
        if main_a != main_b:  # a main-road movement against a minor-road one: the minor one yields
            assert who == (YIELD_B if main_a else YIELD_A)
            checked += 1
    assert checked > 0
    left = [j for j in source if source[j] in ("0", "2") and wrap_angle(
        rm.lanes[j].vertex_heading[-1] - rm.lanes[j].vertex_heading[0]) > 0.5]
    straight = [j for j in source if source[j] in ("0", "2") and j not in left and abs(wrap_angle(
        rm.lanes[j].vertex_heading[-1] - rm.lanes[j].vertex_heading[0])) < 0.1]
    assert left and straight and max(rm.lanes[j].priority for j in left) < min(rm.lanes[j].priority for j in straight)


def test_stop_signs_on_an_imported_junction_hold_traffic_and_the_autopilot(tmp_path, drive_episode, traffic_alone):
    env = make_env("urban", "opendrive", opendrive=_ranked_four_way(tmp_path), junction_control="stop")
    info = drive_episode(env, make_policy("autopilot", env), seed=0)
    assert info["success"] and not info["collision"] and not info.get("violation"), info
    traffic = env.unwrapped.task.traffic
    passed, overlaps, _ = traffic_alone(traffic, 180.0)  # three minutes of its traffic alone
    assert overlaps == 0 and traffic.stats["stop_sign_violations"] == 0
    assert passed[traffic.junctions.group == MINOR_ROAD].sum() >= 3  # the minor road flows through its stop signs


def test_an_imported_map_is_the_same_in_every_process():
    """The lane graph of an imported map does not depend on the process (pyxodr hands the successors over as a set,
    whose order follows the objects' hashes): two interpreters with other hash seeds build the same successors,
    junction entries and give-way lines, so traffic on it repeats with its seed."""
    code = ("import hashlib; from mjdrive.assets import MAPS_DIR; from mjdrive.roads.opendrive import read_opendrive; "
            "rm = read_opendrive(MAPS_DIR / 'roundabout.xodr'); "
            "print(hashlib.sha256(repr((rm.successors, rm.junction_entries, rm.give_way, "
            "[lane.priority for lane in rm.lanes])).encode()).hexdigest())")
    digests = {subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                              env={**os.environ, "PYTHONHASHSEED": str(seed)}).stdout.strip()
               for seed in (1, 2, 3)}
    assert len(digests) == 1 and len(next(iter(digests))) == 64


def _entry_of_road(rm, road: str) -> int:
    """The lane of OpenDRIVE road `road` that enters the four-way junction (lane -1, driving along the road)."""
    return rm.lane_id(f"road{road}/section0/lane-1")


def test_the_files_signals_mark_the_entries_they_face(tmp_path):
    """Stop signs and lights from <signal> and <signalReference>: an entry is marked when the signal faces its
    direction of travel and lanes; signs mjdrive does not model (give way, 205) and signals facing lanes that leave
    the junction are left out; lights are grouped by the junction's controllers, or by heading without them."""
    lights = read_opendrive(MAPS_DIR / "four_way_lights.xodr")
    entries = {_entry_of_road(lights, road): group for road, group in
               (("0", MAIN_ROAD), ("1", MINOR_ROAD), ("2", MAIN_ROAD), ("3", MINOR_ROAD))}
    assert dict(lights.junction_entries) == entries and lights.entry_signs == dict.fromkeys(entries, "lights")
    tree = etree.parse(str(MAPS_DIR / "four_way_lights.xodr"))
    root = tree.getroot()
    for element in root.iter("controller"):
        element.getparent().remove(element)
    path = tmp_path / "uncontrolled.xodr"
    tree.write(str(path))
    assert dict(read_opendrive(path).junction_entries) == entries  # by heading: the first entry's axis is main

    tree = etree.parse(str(MAPS_DIR / "four_way.xodr"))
    roads = {road.get("id"): road for road in tree.getroot().iter("road")}

    def add(road: str, tag: str, **attributes) -> None:
        signals = roads[road].find("signals")
        if signals is None:
            signals = etree.SubElement(roads[road], "signals")
        etree.SubElement(signals, tag, **attributes)

    add("1", "signal", id="1", s="78", t="-4", type="206", orientation="+", dynamic="no")  # stop, faces the entry
    add("0", "signal", id="2", s="2", t="4", type="206", orientation="-", dynamic="no")  # faces the lane leaving
    add("3", "signal", id="3", s="78", t="-4", type="205", orientation="+", dynamic="no")  # give way: not modelled
    add("2", "signalReference", id="1", s="78", t="-4", orientation="+")  # road 1's stop sign, seen on road 2
    add("3", "signal", id="4", s="78", t="-4", name="StopSign", type="-1", orientation="+", dynamic="no")
    validity = etree.SubElement(roads["3"].find("signals")[-1], "validity", fromLane="-2", toLane="-2")
    assert validity is not None  # lane -2 only: road 3 has none, so its entry stays unmarked
    path = tmp_path / "signs.xodr"
    tree.write(str(path))
    rm = read_opendrive(path)
    assert rm.entry_signs == {_entry_of_road(rm, "1"): "stop", _entry_of_road(rm, "2"): "stop"}
    assert sorted(dict(rm.junction_entries)) == sorted(rm.entry_signs)


def test_the_lights_of_an_imported_map_hold_traffic_and_the_autopilot(drive_episode, traffic_alone):
    """urban/opendrive runs under the file's own signals: the ego sees them, the autopilot obeys them, and the
    traffic stops at red for three minutes without a violation or an overlap while every arm keeps flowing."""
    env = make_env("urban", "opendrive", opendrive="four_way_lights")
    observation, _ = env.reset(seed=2)
    assert observation["junction"].shape == (5,) and observation["junction"][:4].sum() == 1.0
    info = drive_episode(env, make_policy("autopilot", env), seed=2)
    assert info["success"] and not info["collision"] and info["violation"] is None, info
    traffic = env.unwrapped.task.traffic
    assert traffic.junctions.active and (traffic.junctions.kind == jc.LIGHTS).all()
    passed, overlaps, red = traffic_alone(traffic, 180.0)
    assert red.all() and overlaps == 0 and traffic.stats["red_light_violations"] == 0
    assert (passed >= 3).all(), passed
    plain = make_env("urban", "opendrive", opendrive="four_way")  # no signals in the file: give way, as before
    assert "junction" not in plain.observation_space.spaces
    plain.reset(seed=0)
    assert not plain.unwrapped.task.traffic.junctions.active
