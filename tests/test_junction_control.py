"""Junction control at the crossroad: the lights' cycle against its timing, traffic that stops at red lights and
at stop signs (and a violation counted when a vehicle cannot stop), the ego's observation, the autopilot obeying
and an always-go driver's violations ending its episode."""

from __future__ import annotations

import numpy as np
import pytest

from mjdrive import suite
from mjdrive.config import ConfigError
from mjdrive.envs import make_env
from mjdrive.policies import make_policy
from mjdrive.roads import concatenated
from mjdrive.roads.roadmap import MAIN_ROAD, MINOR_ROAD
from mjdrive.traffic import Traffic
from mjdrive.traffic import junction_control as jc
from mjdrive.traffic.urban import URBAN_CONFIG, urban_traffic

SUBSTEP = URBAN_CONFIG.substep  # [s]


def test_the_lights_follow_their_timing():
    """Main green, amber, all red, minor green, amber, all red; never both groups green or amber."""
    timing = jc.SignalTiming(green_main=10.0, green_minor=6.0, amber=2.0, all_red=1.0)
    junctions = jc.Junctions.of(concatenated(order=("crossroad",)).road_map).controlled(jc.LIGHTS, timing)
    main, minor = junctions.group == MAIN_ROAD, junctions.group == MINOR_ROAD
    expected = [(0.5, jc.GREEN, jc.RED), (10.5, jc.AMBER, jc.RED), (12.5, jc.RED, jc.RED), (13.5, jc.RED, jc.GREEN),
                (19.5, jc.RED, jc.AMBER), (21.5, jc.RED, jc.RED), (22.5, jc.GREEN, jc.RED)]
    for t, main_state, minor_state in expected:
        states = jc.entry_states(junctions, t)
        assert set(states[main]) == {main_state} and set(states[minor]) == {minor_state}, t
    assert timing.cycle == 22.0
    for t in np.arange(0.0, 44.0, 0.1):
        states = jc.entry_states(junctions, t)
        assert (states[main] == jc.RED).all() or (states[minor] == jc.RED).all()
    stops = jc.entry_states(junctions.controlled(jc.STOP_SIGNS), 3.0)
    assert (stops[minor] == jc.STOP_SIGN).all() and (stops[main] == jc.GREEN).all()


def _alone(control: str, lane_name: str, s: float, speed: float, seconds: float):
    """One car on `lane_name` of the crossroad under `control`, its speed [m/s] at the junction entry sampled:
    (traffic, the lowest speed within HALT_RANGE before the line, whether it entered the junction)."""
    composed = concatenated(order=("crossroad",))
    traffic = urban_traffic(composed, counts={"car": 1})
    traffic.set_junction_control(control)
    traffic.reset(np.random.default_rng(0))
    traffic.remove_all()
    rm = composed.road_map
    lane = rm.lane_id(lane_name)
    traffic.place(0, [lane], s, speed, desired_speed=speed)
    line = rm.lanes[lane].length - jc.STOP_MARGIN
    slowest, entered = np.inf, False
    for _ in range(int(round(seconds / SUBSTEP))):
        traffic.advance(SUBSTEP)
        v = traffic.vehicles
        if v.path[0, 0] == lane:
            front = v.s[0] + v.length[0] / 2
            if 0.0 < line - front < jc.HALT_RANGE:
                slowest = min(slowest, v.v[0])
        elif v.active[0]:
            entered = True
    return traffic, slowest, entered


def test_a_car_comes_to_rest_at_a_stop_sign_then_goes():
    traffic, slowest, entered = _alone("stop", "crossroad/approach_in_0", 10.0, 8.0, 30.0)
    assert slowest < jc.HALT_SPEED and entered
    assert traffic.stats["stop_sign_violations"] == 0
    _, slowest_give_way, entered = _alone("give_way", "crossroad/approach_in_0", 10.0, 8.0, 30.0)
    assert entered and slowest_give_way > 1.0  # a give-way line with nobody coming: it does not stop


def test_a_red_light_holds_a_car_and_one_that_cannot_stop_is_counted():
    composed = concatenated(order=("crossroad",))
    rm = composed.road_map
    lane = rm.lane_id("crossroad/approach_in_0")  # minor road: red for the first green_main + amber + all_red
    traffic = urban_traffic(composed, counts={"car": 2})
    traffic.set_junction_control("lights")
    traffic.reset(np.random.default_rng(0))
    traffic.remove_all()
    line = rm.lanes[lane].length - jc.STOP_MARGIN
    traffic.place(0, [lane], 10.0, 8.0, desired_speed=8.0)  # far enough to stop; red until 25 s
    for _ in range(int(round(20.0 / SUBSTEP))):
        traffic.advance(SUBSTEP)
    v = traffic.vehicles
    assert v.path[0, 0] == lane and v.v[0] < 0.1 and 0.0 < line - (v.s[0] + v.length[0] / 2) < 4.0
    # a car placed 3 m before the line at 12 m/s cannot stop (it would need 24 m/s^2): it runs the red light
    traffic.place(1, [rm.lane_id("crossroad/straight_in_0")], rm.lanes[rm.lane_id("crossroad/straight_in_0")].length
                  - jc.STOP_MARGIN - 3.0 - v.length[1] / 2, 12.0, desired_speed=12.0)
    for _ in range(int(round(3.0 / SUBSTEP))):
        traffic.advance(SUBSTEP)
    assert traffic.stats["red_light_violations"] == 1


@pytest.mark.parametrize("control", ["stop", "lights"])
def test_ten_minutes_of_controlled_traffic_without_violation_or_overlap(control, traffic_alone):
    """Study 002's crossroad at its default traffic under stop signs or lights: nobody runs a red light or a stop
    sign, no two road users overlap, and every approach keeps flowing."""
    composed = concatenated(order=("crossroad",))
    traffic = urban_traffic(composed)
    traffic.set_junction_control(control, offset=5.0)
    traffic.reset(np.random.default_rng(1))
    passes, overlaps, _ = traffic_alone(traffic, 600.0)
    assert overlaps == 0
    assert traffic.stats["red_light_violations"] == 0 and traffic.stats["stop_sign_violations"] == 0
    assert (passes >= 10).all(), passes  # vehicles through every approach


def test_the_ego_sees_the_signal_and_an_always_go_driver_runs_it(drive_episode):
    env = make_env("urban", "crossroad", junction_control="lights")
    observation, _ = env.reset(seed=1)
    assert observation["junction"].shape == (5,) and observation["junction"][:4].sum() == 1.0
    info = drive_episode(env, make_policy("always_go", env), seed=1)
    assert info["violation"] == "red_light" and not info["success"]
    info = drive_episode(env, make_policy("autopilot", env), seed=1)
    assert info["success"] and info["violation"] is None
    env = make_env("urban", "crossroad", junction_control="stop")
    info = drive_episode(env, make_policy("always_go", env), seed=1)
    assert info["violation"] == "stop_sign"
    info = drive_episode(env, make_policy("autopilot", env), seed=1)
    assert info["success"] and info["violation"] is None
    assert "junction" not in make_env("urban", "crossroad").observation_space.spaces  # give-way: as before


def test_random_control_is_drawn_per_episode_and_seeded():
    env = make_env("urban", "crossroad", junction_control="random")
    drawn = []
    for seed in range(12):
        env.reset(seed=seed)
        drawn.append(env.unwrapped.task.junction_control)
    assert set(drawn) == {"give_way", "stop", "lights"}
    again = []
    for seed in range(12):
        env.reset(seed=seed)
        again.append(env.unwrapped.task.junction_control)
    assert again == drawn


def test_bad_junction_keywords():
    with pytest.raises(ConfigError, match=r"junction_control='roundabout': must be one of 'give_way', 'stop', "
                                          r"'lights', 'map', 'random'"):
        suite.load("urban", "crossroad", task_kwargs={"junction_control": "roundabout"})
    with pytest.raises(ConfigError, match=r"signals\.amber=0: must be >= 1"):
        suite.load("urban", "crossroad", task_kwargs={"signals": {"amber": 0}})
    with pytest.raises(ValueError, match="junction control 'red'"):
        Traffic(concatenated(order=("crossroad",)).road_map, ["car"]).set_junction_control("red")
