"""Maps as data: the urban tasks' `map` keyword (the pieces' order and parameters, or a map file), its errors,
its documentation, and traffic, the autopilot and the decision actions on a map nobody registered."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from mjdrive import suite
from mjdrive.config import ConfigError
from mjdrive.envs import make_env
from mjdrive.policies import make_policy
from mjdrive.roads import UrbanMap, concatenated
from mjdrive.traffic.urban import DEFAULT_COUNTS, default_counts

# the crossroad and the merge reversed from Fig. 8, narrow lanes, a sharp crossing and a steep merge
SHORT_MAP = {"order": ["crossroad", "merge"], "lane_width": 3.0,
             "crossroad": {"crossing_angle": math.radians(65), "turn": "left"},
             "merge": {"merge_angle": math.radians(80), "slip_radius": 15.0, "main_lanes": 2}}


def test_map_keywords_reorder_and_change_the_pieces():
    env = suite.load("urban", "concatenated", task_kwargs={"map": SHORT_MAP, "random": 0})
    task = env.task
    assert task.urban.tactical.names == ("crossroad", "merge")
    rm = task.road_map
    assert min(rm.lanes[i].width for i in task.route) == pytest.approx(3.0)
    assert any(rm.lanes[i].name == "crossroad/approach->left_0" for i in task.route)  # the chosen turn
    default = suite.load("urban", "concatenated", task_kwargs={"random": 0}).task
    assert default.urban.tactical.names == ("roundabout", "lane_change", "crossroad", "merge")
    assert task.urban.length < 0.6 * default.urban.length


def test_a_map_file_is_the_same_map_as_its_keywords(tmp_path):
    yaml_file, json_file = tmp_path / "map.yaml", tmp_path / "map.json"
    yaml_file.write_text("order: [crossroad, merge]\nlane_width: 3.0\ncrossroad:\n  crossing_angle: "
                         f"{math.radians(65)}\n  turn: left\nmerge: {{merge_angle: {math.radians(80)}, "
                         "slip_radius: 15.0, main_lanes: 2}\n")
    json_file.write_text(json.dumps(SHORT_MAP))
    routes = [suite.load("urban", "concatenated", task_kwargs={"map": value}).task.urban
              for value in (SHORT_MAP, str(yaml_file), json_file)]
    for route in routes[1:]:
        np.testing.assert_array_equal(route.polyline, routes[0].polyline)
        assert route.route == routes[0].route
    config = suite.task_config("urban", "concatenated")[0].from_dict({"map": str(yaml_file)})
    assert config.to_dict()["map"]["crossroad"]["turn"] == "left"  # checkpoints and logs carry the map, not the path


BAD_MAPS = [
    ({"lane_width": 2.5}, r"lane_width=2\.5: roundabout\.lane_width=2\.5: must be >= 3"),  # the roundabout's own bound
    ({"crossroad": {"lane_width": 6.0}}, r"map\.crossroad\.lane_width=6\.0: must be >= 2\.5 and <= 5 \[m\]"),
    ({"roundabout": {"radiuss": 20}}, r"map\.roundabout: unknown keyword 'radiuss' \(did you mean 'radius'\?\)"),
    ({"order": ["crossroad", "bridge"]}, r"map\.order=.*element 'bridge' is not one of"),
    ({"order": ["merge", "merge"]}, r"map\.order=.*must not repeat"),
    ({"merge": {"merge_angle": 0.4, "slip_radius": 9.0}}, r"map\.merge\.slip_radius=9\.0: must be >="),
    ({"bridge": {}}, r"map: unknown keyword 'bridge'; valid keywords: order, roundabout, road, crossroad, merge"),
    ("no/such/map.yaml", r"map: cannot read the file 'no/such/map.yaml': No such file or directory$"),
]


@pytest.mark.parametrize("value, message", BAD_MAPS, ids=[m.split(":")[0] for _, m in BAD_MAPS])
def test_bad_maps_name_the_piece_and_the_parameter(value, message):
    with pytest.raises(ConfigError, match=r"^urban/concatenated: " + message):
        suite.load("urban", "concatenated", task_kwargs={"map": value})


def test_bad_map_files(tmp_path):
    broken, listed = tmp_path / "broken.yaml", tmp_path / "list.yaml"
    broken.write_text("crossroad: [\n")
    listed.write_text("- crossroad\n")
    with pytest.raises(ConfigError, match=r"map: the file '.*broken.yaml' is not YAML or JSON \(line 2, column 1\)$"):
        suite.load("urban", "crossroad", task_kwargs={"map": str(broken)})
    with pytest.raises(ConfigError, match=r"must hold a mapping of keywords, not list"):
        suite.load("urban", "crossroad", task_kwargs={"map": str(listed)})
    bad_value = tmp_path / "bad.yaml"
    bad_value.write_text("crossroad: {minor_lanes: 9}\n")
    with pytest.raises(ConfigError, match=r"map \(file '.*bad.yaml'\)\.crossroad\.minor_lanes=9: must be"):
        suite.load("urban", "crossroad", task_kwargs={"map": str(bad_value)})


def test_a_scenario_task_needs_its_piece_and_overlapping_pieces_are_refused():
    with pytest.raises(ConfigError, match=r"urban/merge needs the 'merge' piece"):
        suite.load("urban", "merge", task_kwargs={"map": {"order": ["crossroad"]}})
    # a scenario task takes a longer map: it starts start_before m ahead of its own scenario
    task = suite.load("urban", "merge", task_kwargs={"map": {"order": ["crossroad", "merge"]}}).task
    assert task.start_s == pytest.approx(task.urban.tactical.interval("merge")[0] - task.config.start_before)


def test_the_cli_reports_a_bad_map_in_one_line():
    result = subprocess.run([sys.executable, "-m", "mjdrive.cli", "run", "--task", "urban/crossroad", "--episodes",
                             "1", "--task-kwarg", "map={crossroad: {lane_width: 9}}"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "map.crossroad.lane_width=9" in lines[0] and "Traceback" not in result.stderr


def test_list_kwargs_documents_the_map():
    result = subprocess.run([sys.executable, "-m", "mjdrive.cli", "list", "--kwargs", "urban/concatenated"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0
    text = result.stdout
    for name in ("map", "map.roundabout", "map.road", "map.crossroad", "map.merge"):
        assert f"`{name}`: keywords of" in text
    assert "| `crossing_angle` | float |" in text and "| `order` |" in text


def test_default_traffic_scales_with_the_map():
    """Registered maps keep their rows; a resized piece scales its piece's density; a chain carries CHAIN_SHARE."""
    assert default_counts(concatenated()) == DEFAULT_COUNTS["roundabout+overtaking_road+crossroad+merge_road"]
    assert default_counts(concatenated(order=("crossroad",))) == DEFAULT_COUNTS["crossroad"]
    small = default_counts(concatenated(order=("crossroad",), crossroad={"arm_length": 25.0, "approach_length": 25.0}))
    big = default_counts(concatenated(order=("crossroad",), crossroad={"arm_length": 150.0, "approach_length": 150.0}))
    assert small["car"] < DEFAULT_COUNTS["crossroad"]["car"] < big["car"]
    reordered = default_counts(concatenated(order=("merge", "crossroad", "road", "roundabout")))
    assert abs(reordered["car"] - 26) <= 1  # the same pieces in another order: about the study's route
    # a junction's traffic follows its roads' length, not its lanes: more lanes or a skewed crossing (longer
    # connectors) carry no more vehicles through the same conflicts; a road's more lanes do carry more
    for crossroad in ({"main_lanes": 2}, {"minor_lanes": 3}, {"crossing_angle": 2.2}, {"lane_width": 5.0}):
        assert default_counts(concatenated(order=("crossroad",), crossroad=crossroad)) == DEFAULT_COUNTS["crossroad"]
    wide_road = default_counts(concatenated(order=("road",), road={"lanes": 3, "opposite_lanes": 2}))
    assert wide_road["car"] > DEFAULT_COUNTS["overtaking_road"]["car"]


def test_the_autopilot_and_the_rules_drive_a_new_map(drive_episode):
    """Traffic with intentions, conflict zones, the autopilot and the decision actions work unchanged on a map
    only given as keywords."""
    kwargs = {"map": SHORT_MAP, "time_limit": 150.0, "warmup": 5.0}
    env = make_env("urban", "concatenated", **kwargs)
    info = drive_episode(env, make_policy("autopilot", env), seed=3)
    assert info["success"] and not info["collision"], info
    env = make_env("urban", "concatenated", decisions=True, **kwargs)
    info = drive_episode(env, make_policy("rules", env), seed=3)
    assert info["success"] and not info["collision"], info
    assert UrbanMap.from_dict(SHORT_MAP).pieces() == ("crossroad", "merge")


def test_a_car_turning_beside_the_waiting_ego_does_not_wait_for_it(drive_episode):
    """With 3 m lanes, a car turning right into the ego's arm passes one lane width from the ego waiting at its
    give-way line; its corridor used to catch the oncoming ego, and each waited for the other until the time
    limit (this seed). An ego on its lanes keeps to them, as traffic does: it arrives."""
    from tools.urban_maps import REORDERED

    env = make_env("urban", "concatenated", map=REORDERED, time_limit=400.0)
    info = drive_episode(env, make_policy("autopilot", env), seed=40002)
    assert info["success"] and info["elapsed_time"] < 300.0, info


def test_the_map_files_traffic_runs_without_overlap():
    """The committed map file (results/urban/maps/merge_first.yaml), its default traffic alone for 5 simulated minutes
    on seed 2: once 41 substeps of overlap at its 110° crossroad, when a yielding car counted a motorcycle's arrival at
    its present pace of 2 m/s and the motorcycle sped up through the zone (`conflicts.reach_time` counts that)."""
    from pathlib import Path

    from tools.urban_traffic import map_argument, run

    map_file = Path(__file__).resolve().parents[1] / "results" / "urban" / "maps" / "merge_first.yaml"
    result = run(map_argument(str(map_file)), 2, 5.0)
    assert result["overlaps"] == 0
    assert result["stop_free"] < 40.0
