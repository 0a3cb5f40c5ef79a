"""Car models tested against physics, for every model at the default physics step and at 2 ms (the step of
the logs written before the default changed); control at 20 Hz."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from mjdrive import XML_DIR
from mjdrive.vehicle import (
    BRAKE_HOLD_SPEED,
    VEHICLES,
    WHEELS,
    Vehicle,
    ackermann,
    add_vehicle,
    commands_to_ctrl,
)
from mjdrive.world import PHYSICS_TIMESTEP
from tools.physics_dt import drive

DTS = sorted({PHYSICS_TIMESTEP, 0.002})  # [s] physics steps under test: the default and 2 ms
CONTROL_PERIOD = 0.05  # [s] control at 20 Hz
MODELS = sorted(VEHICLES)
KMH = 1 / 3.6  # [m/s] per km/h
# 0-50 km/h at full throttle [s], measured at 2, 3, 4 and 5 ms alike (results/physics_dt.md)
ZERO_TO_50 = {"sedan": 4.95, "suv": 5.90}


def scene(model_name: str, prefix: str = "ego/", dt: float = PHYSICS_TIMESTEP) -> mujoco.MjSpec:
    """The flat world of mjdrive.world.scene_spec (ground.xml) with one car at physics step `dt` [s]; built
    from the xml so these tests do not depend on the rest of the world-building stack."""
    spec = mujoco.MjSpec.from_file(str(XML_DIR / "scenes" / "ground.xml"))
    spec.option.timestep = dt
    add_vehicle(spec, model_name, prefix)
    return spec


@pytest.fixture(scope="module", params=[(m, dt) for m in MODELS for dt in DTS],
                ids=[f"{m}-{dt * 1e3:g}ms" for m in MODELS for dt in DTS])
def car(request) -> tuple[mujoco.MjModel, Vehicle]:
    name, dt = request.param
    model = scene(name, dt=dt).compile()
    return model, Vehicle(model)


def nsub(model: mujoco.MjModel) -> int:
    """Physics steps per control step of `model` (20 Hz)."""
    return int(round(CONTROL_PERIOD / model.opt.timestep))


def tire_mu(model: mujoco.MjModel, vehicle: Vehicle) -> float:
    """The friction the tire-ground contacts use: the tire's (it has the higher contact priority)."""
    tire = model.geom(vehicle.prefix + "tire_fl")
    ground = model.geom("ground")
    assert tire.priority[0] > ground.priority[0]
    return float(tire.friction[0])


def test_braking_distance_from_50kmh(car):
    model, veh = car
    data = mujoco.MjData(model)
    v0 = 50 * KMH
    veh.reset(data, 0.0, 0.0, 0.0, v0)
    accel: list[float] = []  # [m/s^2] longitudinal
    drive(model, data, veh, lambda t, d: (0.0, 0.0, 1.0), 4.0,
          lambda t, d: accel.append(veh.acceleration(d)[0]))
    mu, g = tire_mu(model, veh), -model.opt.gravity[2]
    assert mu == pytest.approx(veh.params.tire_mu)
    theory = v0**2 / (2 * mu * g)
    x, y, yaw = veh.pose(data)
    assert abs(veh.speed(data)) < 0.01
    # The published +5.7 ... +6.4% (docs/vehicles.md, results/physics_dt.md; the tyres slip, never lock)
    # within 2 points; the SUV's +9.4% at 8 ms fails.
    assert 0.04 < x / theory - 1 < 0.08, (x, theory)
    assert abs(y) < 0.05 and abs(yaw) < 0.01
    assert min(accel) > -1.3 * mu * g  # no impacts: the wheels do not lock, hop or chatter


@pytest.mark.parametrize("steer", [0.25, 0.5, 1.0, -0.6])
def test_low_speed_circle_radius(car, steer):
    model, veh = car
    p = veh.params
    data = mujoco.MjData(model)
    veh.reset(data, 0.0, 0.0, 0.0, 3.0)
    points: list[tuple[float, float]] = []

    def log(t, d):
        if t > 4.0:  # steady state
            x, y, yaw = veh.pose(d)
            points.append((x - 0.5 * p.wheelbase * math.cos(yaw), y - 0.5 * p.wheelbase * math.sin(yaw)))

    def policy(t, d):  # hold ~3 m/s
        return min(1.0, max(0.0, 0.5 * (3.0 - veh.speed(d)))), steer, 0.0

    drive(model, data, veh, policy, 16.0, log)
    xy = np.array(points)  # rear-axle centre
    a = np.c_[2 * xy, np.ones(len(xy))]
    cx, cy, c = np.linalg.lstsq(a, (xy**2).sum(1), rcond=None)[0]
    radius = math.sqrt(c + cx**2 + cy**2)
    theory = p.wheelbase / math.tan(abs(steer) * p.max_steer)
    # The published +0.01 ... +0.25% (docs/vehicles.md, results/physics_dt.md): never below the kinematic radius,
    # at most 0.5% above it.
    assert 0.0 < radius / theory - 1 < 0.005, (radius, theory)
    assert np.sign(veh.yaw_rate(data)) == np.sign(steer)
    assert veh.steering_angle(data) == pytest.approx(steer * p.max_steer, abs=0.01)


def test_zero_to_50kmh(car):
    model, veh = car
    data = mujoco.MjData(model)
    veh.reset(data, 0.0, 0.0, 0.0)
    t = drive(model, data, veh, lambda t, d: (1.0, 0.0, 0.0), 15.0, until=lambda d: veh.speed(d) >= 50 * KMH)
    assert veh.speed(data) >= 50 * KMH
    assert t == pytest.approx(ZERO_TO_50[veh.params.name], abs=0.1), t


@pytest.mark.parametrize("brake", [1.0, 0.0])
def test_parked_car_stays(car, brake):
    model, veh = car
    data = mujoco.MjData(model)
    veh.reset(data, 3.0, -2.0, 0.7)
    start = data.xpos[veh.body_id].copy()
    drive(model, data, veh, lambda t, d: (0.0, 0.0, brake), 10.0)
    assert np.linalg.norm(data.xpos[veh.body_id] - start) < 5e-4  # [m], settling included (measured 0.02 mm)
    assert abs(veh.pose(data)[2] - 0.7) < 1e-3


def test_top_speed_and_straight_line(car):
    model, veh = car
    p = veh.params
    data = mujoco.MjData(model)
    x0, y0, yaw0 = 5.0, -3.0, 0.3  # off-axis heading, so the check is not helped by symmetry
    veh.reset(data, x0, y0, yaw0)
    speeds: list[float] = []
    lateral: list[float] = []  # [m] offset from the start line while within the first 100 m
    side_slip: list[float] = []  # [m/s] body lateral velocity

    def log(t, d):
        x, y, _ = veh.pose(d)
        along = (x - x0) * math.cos(yaw0) + (y - y0) * math.sin(yaw0)
        if along <= 100.0:
            lateral.append(-(x - x0) * math.sin(yaw0) + (y - y0) * math.cos(yaw0))
        speeds.append(veh.speed(d))
        side_slip.append(veh.velocity_body(d)[1])

    drive(model, data, veh, lambda t, d: (1.0, 0.0, 0.0), 120.0, log)
    top = speeds[-1]
    assert 120 * KMH < top < 250 * KMH, top / KMH
    assert max(speeds) < 1.01 * p.top_speed  # bounded by the drive torque curve
    last_10s = int(round(10 / (nsub(model) * model.opt.timestep)))  # control steps
    assert speeds[-1] - speeds[-last_10s] < 1 * KMH  # settled: < 1 km/h gained in the last 10 s
    assert top == pytest.approx(p.top_speed, rel=0.02)
    assert max(np.abs(lateral)) < 0.5
    assert max(np.abs(side_slip)) < 0.02  # no crabbing


def test_commands_validated_and_clipped(car):
    model, veh = car
    data = mujoco.MjData(model)
    veh.reset(data, 0.0, 0.0, 0.0, 10.0)
    for bad in [(math.nan, 0.0, 0.0), (0.0, math.inf, 0.0), (0.0, 0.0, -math.inf)]:
        with pytest.raises(ValueError, match="finite"):
            veh.apply(data, *bad)
    with pytest.raises(ValueError):
        commands_to_ctrl(np.array([[0.0, 0.0, 0.0], [0.0, math.nan, 0.0]]), veh.params, 0.0)
    with pytest.raises(ValueError, match="shape"):
        commands_to_ctrl(np.zeros(4), veh.params, 0.0)
    veh.apply(data, 1.0, -1.0, 1.0)
    clipped = data.ctrl[veh.actuator_ids].copy()
    veh.apply(data, 7.0, -3.0, 2.5)
    np.testing.assert_array_equal(data.ctrl[veh.actuator_ids], clipped)
    veh.apply(data, -1.0, 0.0, -1.0)
    assert not data.ctrl[veh.actuator_ids[2:]].any()
    lo, hi = model.actuator_ctrlrange[veh.actuator_ids].T
    assert np.all(clipped >= lo) and np.all(clipped <= hi)


def test_commands_to_ctrl_vectorised(car):
    _, veh = car
    p = veh.params
    rng = np.random.default_rng(0)
    commands = rng.uniform(-1.5, 1.5, size=(4, 5, 3))
    speeds = rng.uniform(-5.0, 30.0, size=(4, 5))
    ctrl = commands_to_ctrl(commands, p, speeds)
    assert ctrl.shape == (4, 5, p.n_ctrl)
    for i, j in np.ndindex(4, 5):
        np.testing.assert_allclose(ctrl[i, j], commands_to_ctrl(commands[i, j], p, speeds[i, j]))
    left, right = ackermann(0.3, p.wheelbase, p.track)  # both wheel axes meet on the rear-axle line
    assert p.wheelbase / math.tan(left) + p.track / 2 == pytest.approx(p.wheelbase / math.tan(0.3))
    assert p.wheelbase / math.tan(right) - p.track / 2 == pytest.approx(p.wheelbase / math.tan(0.3))
    brake = commands_to_ctrl(np.array([0.0, 0.0, 0.5]), p, np.array([0.0, 10.0]))[..., -1]
    np.testing.assert_allclose(brake, [0.5, 0.5 * BRAKE_HOLD_SPEED / 10.0])


def test_apply_writes_commands_to_ctrl_bit_for_bit(car):
    """`Vehicle.apply` (scalars, the per-step path) and `commands_to_ctrl` (arrays) give the same bytes,
    clipped signed zeros and the brake hold below BRAKE_HOLD_SPEED included."""
    model, veh = car
    data = mujoco.MjData(model)
    rng = np.random.default_rng(1)
    special = [-0.0, 0.0, 1.0, -1.0, 2.0, -3.0, 0.5]
    for _ in range(300):
        command = [float(rng.choice(special)) if rng.random() < 0.3 else float(rng.uniform(-1.5, 1.5))
                   for _ in range(3)]
        veh.reset(data, 0.0, 0.0, 0.0, float(rng.choice([0.0, -0.1, BRAKE_HOLD_SPEED, rng.uniform(-5.0, 40.0)])))
        veh.apply(data, *command)
        expected = commands_to_ctrl(np.array(command), veh.params, veh.speed(data))
        assert data.ctrl[veh.actuator_ids].tobytes() == expected.tobytes(), command


def test_models_differ():
    sedan, suv = VEHICLES["sedan"], VEHICLES["suv"]
    assert sedan.mass != suv.mass and sedan.wheelbase != suv.wheelbase and sedan.track != suv.track
    assert sedan.max_drive_torque != suv.max_drive_torque and sedan.driven_wheels != suv.driven_wheels
    masses = [scene(name).compile().body("ego/chassis").subtreemass[0] for name in ("sedan", "suv")]
    assert masses == pytest.approx([sedan.mass, suv.mass], rel=0.01)


def test_compiled_model_matches_params(car):
    model, veh = car
    p = veh.params
    data = mujoco.MjData(model)
    veh.reset(data, 0.0, 0.0, 0.0)
    pre = veh.prefix
    assert model.body_subtreemass[veh.body_id] == pytest.approx(p.mass, rel=0.01)
    wheel = {w: data.xpos[model.body(pre + f"wheel_{w}").id] for w in WHEELS}
    assert wheel["fl"][0] - wheel["rl"][0] == pytest.approx(p.wheelbase, rel=0.01)
    assert wheel["fl"][1] - wheel["fr"][1] == pytest.approx(p.track, rel=0.01)
    assert wheel["rl"][1] - wheel["rr"][1] == pytest.approx(p.track, rel=0.01)
    tire = model.geom(pre + "tire_fl")
    assert tire.size[0] == pytest.approx(p.wheel_radius) and tire.friction[0] == pytest.approx(p.tire_mu)
    body, cabin = model.geom(pre + "body_col"), model.geom(pre + "cabin_col")
    assert 2 * body.size[0] == pytest.approx(p.length) and 2 * body.size[1] == pytest.approx(p.width)
    assert cabin.pos[2] + cabin.size[2] == pytest.approx(p.height)
    drive_ids = veh.actuator_ids[2 : 2 + len(p.driven_wheels)]
    gain, bias = model.actuator_gainprm[drive_ids], model.actuator_biasprm[drive_ids]
    assert gain[:, 0].sum() == pytest.approx(p.max_drive_torque, rel=0.01)
    assert np.allclose(-bias[:, 2], p.engine_brake)
    v_top = p.wheel_radius * gain[:, 0] / -(gain[:, 2] + bias[:, 2])
    assert np.allclose(v_top, p.top_speed, rtol=0.01)
    kb = -model.actuator_gainprm[veh.actuator_ids[-4:], 2]
    torque = kb * BRAKE_HOLD_SPEED / p.wheel_radius
    np.testing.assert_allclose(torque, np.repeat(p.brake_torque, 2), rtol=0.01)
    inner = ackermann(p.max_steer, p.wheelbase, p.track)[0]
    assert model.actuator_ctrlrange[veh.actuator_ids[0], 1] >= inner
    assert model.jnt_range[model.joint(pre + "steer_fl").id, 1] >= inner


def test_at_rest_only_tires_touch_the_ground_and_body_hits_obstacles(car):
    model, veh = car
    p = veh.params
    data = mujoco.MjData(model)
    veh.reset(data, 0.0, 0.0, 0.0)
    z0 = data.xpos[veh.body_id, 2]
    drive(model, data, veh, lambda t, d: (0.0, 0.0, 1.0), 1.0)
    assert abs(data.xpos[veh.body_id, 2] - z0) < 5e-4  # reset puts it at its rest height: no drop
    tires = {model.geom(veh.prefix + f"tire_{w}").id for w in WHEELS}
    pairs = {tuple(sorted(g)) for g in data.contact.geom[: data.ncon]}
    assert pairs == {tuple(sorted((t, model.geom("ground").id))) for t in tires}

    spec = scene(p.name, dt=model.opt.timestep)  # an obstacle with the traffic bits 2 / 2, 6 m ahead
    box = spec.worldbody.add_body(name="obstacle", pos=[p.length / 2 + 6.0, 0.0, 0.6])
    box.add_geom(name="obstacle", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.5, 1.5, 0.6], contype=2,
                 conaffinity=2)
    model2 = spec.compile()
    veh2, data2 = Vehicle(model2), mujoco.MjData(model2)
    veh2.reset(data2, 0.0, 0.0, 0.0, 5.0)
    hit: set[str] = set()

    def log(t, d):
        for g in d.contact.geom[: d.ncon]:
            names = {model2.geom(g[0]).name, model2.geom(g[1]).name}
            if "obstacle" in names:
                hit.update(names - {"obstacle"})

    drive(model2, data2, veh2, lambda t, d: (0.3, 0.0, 0.0), 3.0, log)
    assert veh2.prefix + "body_col" in hit
    assert veh2.pose(data2)[0] < 6.0 + 0.1  # stopped by the obstacle


def test_reset_moving_and_readouts(car):
    model, veh = car
    p = veh.params
    data = mujoco.MjData(model)
    veh.reset(data, 10.0, 20.0, 1.0, 15.0)
    assert veh.pose(data) == pytest.approx((10.0, 20.0, 1.0))
    assert veh.velocity_body(data) == pytest.approx((15.0, 0.0))
    np.testing.assert_allclose(veh.wheel_speeds(data), 15.0 / p.wheel_radius)
    assert veh.steering_angle(data) == 0.0 and veh.yaw_rate(data) == 0.0
    speeds: list[float] = []
    drive(model, data, veh, lambda t, d: (0.0, 0.0, 0.0), 1.0, log=lambda t, d: speeds.append(veh.speed(d)))
    assert max(speeds) < 15.0 and min(speeds) > 14.0  # coasts smoothly: no start-up transient
    np.testing.assert_allclose(veh.wheel_speeds(data), veh.speed(data) / p.wheel_radius, rtol=0.01)
    # braking: the accelerometer agrees with the change of speed, lateral ~ 0
    v0 = veh.speed(data)
    acc: list[tuple[float, float]] = []
    drive(model, data, veh, lambda t, d: (0.0, 0.0, 0.5), 1.0, lambda t, d: acc.append(veh.acceleration(d)))
    along, side = np.mean(acc, axis=0)
    assert along == pytest.approx(veh.speed(data) - v0, rel=0.1) and abs(side) < 0.05
    assert along < -3.0  # half brake gives about half the 1 g full-brake deceleration


def test_planar_state_is_the_readouts_in_one_call(car):
    model, veh = car
    data = mujoco.MjData(model)
    veh.reset(data, 4.0, -1.0, 2.5, 8.0)
    drive(model, data, veh, lambda t, d: (0.6, 0.7, 0.0), 2.0)  # turning, rolling and pitching a little
    x, y, yaw, forward, left, yaw_rate = veh.planar_state(data)
    assert (x, y, yaw) == veh.pose(data) and (forward, left) == veh.velocity_body(data)  # exactly
    assert yaw_rate == veh.yaw_rate(data) and abs(yaw_rate) > 0.5 and abs(left) > 1e-3


def test_add_vehicle_names_and_errors():
    spec = mujoco.MjSpec.from_file(str(XML_DIR / "scenes" / "ground.xml"))
    with pytest.raises(ValueError, match="sedan"):
        add_vehicle(spec, "truck")
    add_vehicle(spec, "sedan", prefix="a/", pos=(0.0, 0.0, 0.0))
    add_vehicle(spec, "suv", prefix="b/", pos=(0.0, 10.0, 0.0), yaw=math.pi / 2)
    model = spec.compile()
    a, b = Vehicle(model, "a/"), Vehicle(model, "b/")
    assert (a.params.name, b.params.name) == ("sedan", "suv")
    assert model.camera("a/front").id >= 0 and model.camera("b/chase").id >= 0 and model.site("a/imu").id >= 0
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    assert b.pose(data) == pytest.approx((0.0, 10.0, math.pi / 2))
    with pytest.raises(ValueError, match="c/chassis"):
        Vehicle(model, "c/")
    with pytest.raises(ValueError, match="not a suv"):
        Vehicle(model, "a/", "suv")


BOUNCE_XML = """<mujoco><option timestep="{dt}" gravity="0 0 0"/><worldbody>
  <geom name="ground" type="plane" size="20 20 0.1" contype="0" conaffinity="0"/>
  <geom name="wall" type="box" pos="1 0 0.5" size="0.1 1 0.5"/>
  <body name="ego/chassis" pos="0.4 0 0.5"><freejoint/><geom type="box" size="0.3 0.3 0.3" mass="1500"/></body>
</worldbody></mujoco>"""


@pytest.mark.parametrize("contact_sensors", [True, False])
@pytest.mark.parametrize("dt", DTS)
def test_collision_sensor_catches_a_bump_that_bounces_off_within_a_control_step(dt, contact_sensors):
    """A 1500 kg box hits a wall at 3 m/s and bounces back: with MuJoCo's default contact (solref 0.02) it
    touches for ~0.08 s, so a check at the end of a 0.2 s control step misses it; sampling every 0.02 s
    (the tasks' physics chunks) does not. With the world's contact sensors (`world.add_contact_sensors`) or
    without (the contact list)."""
    from mjdrive.sensors import CollisionSensor
    from mjdrive.world import add_contact_sensors

    spec = mujoco.MjSpec.from_string(BOUNCE_XML.format(dt=dt))
    if contact_sensors:
        add_contact_sensors(spec, "ego/")
    model = spec.compile()
    data = mujoco.MjData(model)
    data.qvel[0] = 3.0  # [m/s] towards the wall, 0.2 m away
    sensor = CollisionSensor(model)
    touching = []
    chunk = int(round(0.02 / dt))  # physics steps per 0.02 s sample
    for step in range(int(round(0.2 / dt))):  # one 0.2 s control step
        mujoco.mj_step(model, data)
        touching.append(sensor(data))
        if step % chunk == chunk - 1:
            sensor.sample(data)
    assert data.qvel[0] < -0.1 and not touching[-1]  # bounced off: no contact at the end
    assert 0.02 < dt * sum(touching) < 0.2  # [s] in contact
    assert sensor.collided(data) and not sensor.collided(data)  # reported once, then cleared
    assert model.geom(sensor.last_other_geom).name == "wall"
    assert (sensor._counts is not None) == contact_sensors


def test_contact_sensors_agree_with_the_contact_list():
    """In traffic, with a reckless ego that hits road users: the collision sensor's answer from the world's
    contact sensors equals the scan of the contact list at every physics chunk."""
    from mjdrive import suite
    from mjdrive.sensors import CollisionSensor

    env = suite.load("roundabout", "d210", {"random": 1})
    env.physics.every_chunk = True  # a sample at every chunk (the substep loop checks the counts only)
    scan = CollisionSensor(env.physics.model.ptr)
    scan._counts = None  # the contact list only
    sensor = env.task.collision_sensor
    assert sensor._counts is not None
    answers = []
    sample = sensor.sample
    sensor.sample = lambda data: (answers.append((scan(data), sensor(data))), sample(data))
    rng = np.random.default_rng(0)
    for _ in range(20):
        env.reset()
        for _ in range(150):
            if env.step(np.array([1.0, rng.uniform(-0.3, 0.3), 0.0])).last():
                break
    assert len(answers) > 1000 and sum(hit for hit, _ in answers) >= 5
    assert all(hit == answer for hit, answer in answers)


@pytest.mark.parametrize("dt", DTS)
@pytest.mark.parametrize("name", ["waypoints/straight", "roundabout/d120"])
def test_tasks_sample_contacts_every_20ms_whatever_the_step(name, dt):
    """The collision sensor samples every 0.02 s of physics (the bounce above) at any physics step: 5 samples
    per 0.1 s waypoints step, 10 per 0.2 s roundabout step."""
    from mjdrive import suite

    domain, task = name.split("/")
    env = suite.load(domain, task, {"random": 0, "physics_dt": dt})
    env.physics.every_chunk = True  # the substep loop checks at the same chunks (tests/test_stepping.py)
    env.reset()
    samples = []
    sample = env.task.collision_sensor.sample
    env.task.collision_sensor.sample = lambda data: (samples.append(data.time), sample(data))
    env.step(np.array([0.3, 0.0, 0.0]))
    np.testing.assert_allclose(np.diff(samples), 0.02, atol=1e-9)
    assert len(samples) == round(env.control_timestep() / 0.02)
    env.close()


def test_default_step_drives_like_2ms():
    """The default physics step changes none of the car's figures beyond the measured spread
    (results/physics_dt.md): braking distance within 1%, 0-50 km/h within 0.05 s, circle radius within 0.1%."""
    figures = {}
    for dt in (PHYSICS_TIMESTEP, 0.002):
        for name in MODELS:
            model = scene(name, dt=dt).compile()
            veh = Vehicle(model)
            data = mujoco.MjData(model)
            veh.reset(data, 0.0, 0.0, 0.0, 50 * KMH)
            drive(model, data, veh, lambda t, d: (0.0, 0.0, 1.0), 4.0)
            braking = veh.pose(data)[0]
            data = mujoco.MjData(model)
            veh.reset(data, 0.0, 0.0, 0.0)
            t50 = drive(model, data, veh, lambda t, d: (1.0, 0.0, 0.0), 15.0,
                        until=lambda d, veh=veh: veh.speed(d) >= 50 * KMH)
            data = mujoco.MjData(model)
            veh.reset(data, 0.0, 0.0, 0.0, 3.0)
            drive(model, data, veh, lambda t, d, veh=veh: (min(1.0, max(0.0, 0.5 * (3.0 - veh.speed(d)))), 0.5, 0.0),
                  8.0)
            yaw_rate_over_speed = veh.yaw_rate(data) / veh.speed(data)  # [1/m] curvature of the steady circle
            figures[(name, dt)] = (braking, t50, yaw_rate_over_speed)
    for name in MODELS:
        (b, t, k), (b2, t2, k2) = figures[(name, PHYSICS_TIMESTEP)], figures[(name, 0.002)]
        assert b == pytest.approx(b2, rel=0.01) and t == pytest.approx(t2, abs=0.05), (name, b, b2, t, t2)
        assert k == pytest.approx(k2, rel=1e-3), (name, k, k2)
