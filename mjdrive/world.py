"""World assembly with MjSpec: scene (sky, light, ground) + road meshes + ego car + obstacles + traffic slots.

The ground plane is the physical driving surface; road surfaces and markings are visual meshes a few
millimetres above it (they never collide). Collision bits: the ego's body geoms and the obstacles /
traffic share bit 2 so any contact between them is a real MuJoCo contact (see xml/vehicles/*.xml).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from mjdrive.assets import XML_DIR
from mjdrive.roads import Marking, RoadMap
from mjdrive.roads.geometry import box_points
from mjdrive.vehicle import add_vehicle

PHYSICS_TIMESTEP = 0.005  # [s] chosen by measurement: results/physics_dt.md
ROAD_Z = 0.004  # [m] height of the road surface mesh above the ground plane
MARKING_Z = 0.008  # [m] height of the marking meshes
MARKING_WIDTH = 0.15  # [m]
DASH_ON, DASH_OFF = 3.0, 6.0  # [m] broken-line pattern
GIVE_WAY_DEPTH = 0.3  # [m] give-way line across a lane: its extent along the lane
GIVE_WAY_DASH = (0.6, 0.3)  # [m] its dashes and gaps across the lane
NEAR_CLIP, FAR_CLIP = 0.1, 400.0  # [m] camera clip planes
OBSTACLE_CONTYPE = 2  # collision bit shared by obstacles, traffic and the ego body (not the ground)

ASPHALT_RGBA = (0.32, 0.32, 0.34, 1.0)
JUNCTION_RGBA = (0.34, 0.34, 0.36, 1.0)
WHITE_RGBA = (0.95, 0.95, 0.95, 1.0)
BUILDING_RGBA = (0.7, 0.62, 0.55, 1.0)
CROSSWALK_RGBA = (0.92, 0.92, 0.92, 1.0)


@dataclass(frozen=True)
class TrafficSlot:
    """One kinematic road-user body (mocap) of fixed size: half sizes [m] and colour."""

    kind: str
    half_size: tuple[float, float, float]
    rgba: tuple[float, float, float, float]


def scene_spec(timestep: float = PHYSICS_TIMESTEP) -> mujoco.MjSpec:
    """An empty flat world: ground plane (the drivable surface), sky, light, solver options."""
    spec = mujoco.MjSpec.from_file(str(XML_DIR / "scenes" / "ground.xml"))
    spec.option.timestep = timestep
    return spec


def build_spec(
    road_map: RoadMap | None,
    vehicle: str = "sedan",
    buildings: bool = False,
    traffic: Sequence[TrafficSlot] = (),
    timestep: float = PHYSICS_TIMESTEP,
    seed: int = 0,
) -> mujoco.MjSpec:
    """The MjSpec of a world: ground, road meshes, optional buildings, the ego car ("ego/") and traffic slots."""
    spec = scene_spec(timestep)
    if road_map is not None:
        _add_road_meshes(spec, road_map)
        if buildings:
            _add_buildings(spec, road_map, np.random.default_rng(seed))
    add_vehicle(spec, vehicle, prefix="ego/")
    add_contact_sensors(spec, "ego/")
    chassis = spec.body("ego/chassis")
    top = chassis.add_camera(name="ego/top", pos=[0, 0, 45], mode=mujoco.mjtCamLight.mjCAMLIGHT_TRACK)
    top.fovy = 60
    for i, slot in enumerate(traffic):
        body = spec.worldbody.add_body(name=f"traffic_{i}", mocap=True, pos=[0, 0, -50.0 - 5 * i])
        body.add_geom(
            name=f"traffic_{i}_{slot.kind}", type=mujoco.mjtGeom.mjGEOM_BOX,
            size=list(slot.half_size), pos=[0, 0, slot.half_size[2]], rgba=list(slot.rgba),
            contype=OBSTACLE_CONTYPE, conaffinity=OBSTACLE_CONTYPE,
        )
    return spec


def add_contact_sensors(spec: mujoco.MjSpec, prefix: str = "ego/", ground: str = "ground") -> None:
    """Two MuJoCo contact sensors on the car `prefix`: how many contacts its bodies have (`{prefix}contacts`)
    and how many of them with the ground (`{prefix}ground_contacts`); more of the first means it touches
    something else (`sensors.CollisionSensor` reads them after every physics chunk, at no Python cost)."""
    for name, reftype, refname in (("contacts", mujoco.mjtObj.mjOBJ_UNKNOWN, ""),
                                   ("ground_contacts", mujoco.mjtObj.mjOBJ_GEOM, ground)):
        sensor = spec.add_sensor(name=f"{prefix}{name}", type=mujoco.mjtSensor.mjSENS_CONTACT,
                                 objtype=mujoco.mjtObj.mjOBJ_XBODY, objname=f"{prefix}chassis")
        sensor.reftype, sensor.refname = reftype, refname
        sensor.intprm[0], sensor.intprm[1], sensor.intprm[2] = 1, 0, 1  # data "found", no reduction, one slot


def build(road_map: RoadMap | None, **kwargs) -> mujoco.MjModel:
    """Compile the world of `build_spec(road_map, **kwargs)` into an MjModel (once per task instance, not per
    episode)."""
    model = build_spec(road_map, **kwargs).compile()
    # Clip planes are relative to the model's extent, which a large map inflates: keep them metric.
    model.vis.map.znear = NEAR_CLIP / model.stat.extent
    model.vis.map.zfar = FAR_CLIP / model.stat.extent
    return model


# --- meshes -------------------------------------------------------------------------------------------


def _strip(left: np.ndarray, right: np.ndarray, z: float) -> tuple[np.ndarray, np.ndarray]:
    """Triangles between two polylines of equal length N: vertices (2N,3), faces (2(N-1),3), normals up."""
    n = len(left)
    verts = np.empty((2 * n, 3))
    verts[0::2, :2], verts[1::2, :2] = left, right
    verts[:, 2] = z
    i = np.arange(n - 1)
    l0, r0, l1, r1 = 2 * i, 2 * i + 1, 2 * i + 2, 2 * i + 3
    faces = np.concatenate([np.stack([l0, r0, l1], 1), np.stack([r0, r1, l1], 1)])
    return verts, faces


def _offset(polyline: np.ndarray, d: float) -> np.ndarray:
    """The polyline shifted by d [m] to its left (normals from central differences)."""
    tangent = np.gradient(polyline, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True) + 1e-12
    return polyline + d * np.stack([-tangent[:, 1], tangent[:, 0]], 1)


def _dashes(polyline: np.ndarray) -> list[np.ndarray]:
    """Cut a polyline into DASH_ON pieces separated by DASH_OFF gaps."""
    seg = np.linalg.norm(np.diff(polyline, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    pieces = []
    for start in np.arange(0.0, s[-1], DASH_ON + DASH_OFF):
        stop = min(start + DASH_ON, s[-1])
        ss = np.linspace(start, stop, 4)
        pieces.append(np.stack([np.interp(ss, s, polyline[:, 0]), np.interp(ss, s, polyline[:, 1])], 1))
    return pieces


def _polygon_fan(polygon: np.ndarray, z: float) -> tuple[np.ndarray, np.ndarray]:
    """Triangle fan of a convex polygon (K,2)."""
    k = len(polygon)
    verts = np.column_stack([polygon, np.full(k, z)])
    faces = np.stack([np.zeros(k - 2, int), np.arange(1, k - 1), np.arange(2, k)], 1)
    return verts, faces


def _merge(parts: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    verts, faces, offset = [], [], 0
    for v, f in parts:
        verts.append(v)
        faces.append(f + offset)
        offset += len(v)
    return np.concatenate(verts), np.concatenate(faces)


def _add_mesh_geom(spec: mujoco.MjSpec, name: str, parts, rgba) -> None:
    if not parts:
        return
    verts, faces = _merge(parts)
    # Upward-facing triangles: orient each face counter-clockwise seen from above.
    a, b, c = verts[faces[:, 0], :2], verts[faces[:, 1], :2], verts[faces[:, 2], :2]
    cross = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    faces[cross < 0] = faces[cross < 0][:, [0, 2, 1]]
    mesh = spec.add_mesh(name=name)
    mesh.uservert = verts.astype(np.float32).ravel()
    mesh.userface = faces.astype(np.int32).ravel()
    mesh.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_SHELL
    spec.worldbody.add_geom(
        name=name, type=mujoco.mjtGeom.mjGEOM_MESH, meshname=name, rgba=list(rgba),
        contype=0, conaffinity=0, group=0,
    )


def _add_road_meshes(spec: mujoco.MjSpec, road_map: RoadMap) -> None:
    surface = [_strip(lane.left_edge(), lane.right_edge(), ROAD_Z) for lane in road_map.lanes]
    areas = [_polygon_fan(polygon, ROAD_Z + 0.0005) for polygon in road_map.areas]
    markings = []
    for line, kind in road_map.marking_lines():
        if kind == Marking.NONE or len(line) < 2:
            continue
        for piece in [np.asarray(line, float)] if kind == Marking.SOLID else _dashes(np.asarray(line, float)):
            markings.append(_strip(_offset(piece, MARKING_WIDTH / 2), _offset(piece, -MARKING_WIDTH / 2), MARKING_Z))
    crosswalks = []
    for cw in getattr(road_map, "crosswalks", []):
        along = np.array([np.cos(cw.heading), np.sin(cw.heading)])
        across = np.array([-along[1], along[0]])
        for k in np.arange(-cw.length / 2 + 0.25, cw.length / 2, 1.0):  # zebra stripes 0.5 m every 1 m
            c = np.asarray(cw.centre) + k * along
            corners = [c + sa * 0.25 * along + sb * cw.width / 2 * across for sa, sb in
                       ((-1, -1), (1, -1), (1, 1), (-1, 1))]
            crosswalks.append(_polygon_fan(np.array(corners), MARKING_Z))
    _add_mesh_geom(spec, "road_surface", surface, ASPHALT_RGBA)
    _add_mesh_geom(spec, "road_areas", areas, JUNCTION_RGBA)
    _add_mesh_geom(spec, "markings", markings, WHITE_RGBA)
    _add_mesh_geom(spec, "crosswalks", crosswalks, CROSSWALK_RGBA)
    _add_mesh_geom(spec, "give_way_lines", _give_way_marks(road_map), WHITE_RGBA)


def _give_way_marks(road_map: RoadMap) -> list[tuple[np.ndarray, np.ndarray]]:
    """Broken lines across lanes, ending at each give-way position (lane, s) of the map."""
    parts = []
    on, off = GIVE_WAY_DASH
    for lane_id, s in getattr(road_map, "give_way", []):
        lane = road_map.lanes[lane_id]
        s1 = min(float(s), lane.length)
        s0 = max(s1 - GIVE_WAY_DEPTH, 0.0)
        count = int((lane.width + off) // (on + off))
        first = -(count * on + (count - 1) * off) / 2  # [m] the dashes centred across the lane
        for d0 in first + (on + off) * np.arange(count):
            d = np.array([d0, d0 + on, d0 + on, d0])
            corners = lane.position(np.array([s0, s0, s1, s1]), d)
            parts.append(_polygon_fan(corners, MARKING_Z))
    return parts



def _add_buildings(spec: mujoco.MjSpec, road_map: RoadMap, rng: np.random.Generator) -> None:
    """Line the roads with static boxes ("buildings") placed clear of every lane and junction."""
    candidates = []
    for lane in road_map.lanes:
        if lane.in_junction or lane.length < 20:
            continue
        for s in np.arange(8.0, lane.length - 8.0, 14.0):
            candidates.append((lane.position(s, -(lane.width / 2 + 9.0)), lane.heading(s)))
    if not candidates:
        return
    centres = np.array([c for c, _ in candidates])
    headings = np.array([h for _, h in candidates])
    half = np.array([5.0, 5.0])  # [m] footprint half size
    # Reject a box if any of its corners or its centre is on a road (with a 1 m margin).
    offsets = np.array([[sx, sy] for sx in (-1, 0, 1) for sy in (-1, 0, 1)]) * (half + 1.0)
    points = box_points(centres, headings, offsets).reshape(-1, 2)
    on_road = road_map.on_road(points).reshape(len(centres), -1).any(1)
    kept: list[np.ndarray] = []
    for centre, heading, blocked in zip(centres, headings, on_road, strict=True):
        if blocked or any(np.linalg.norm(centre - k) < 2 * half[0] + 1.0 for k in kept):
            continue
        kept.append(centre)
        height = float(rng.uniform(6.0, 20.0))
        spec.worldbody.add_geom(
            name=f"building_{len(kept) - 1}", type=mujoco.mjtGeom.mjGEOM_BOX,
            size=[half[0], half[1], height / 2], pos=[centre[0], centre[1], height / 2],
            quat=[np.cos(heading / 2), 0, 0, np.sin(heading / 2)], rgba=list(BUILDING_RGBA),
            contype=OBSTACLE_CONTYPE, conaffinity=OBSTACLE_CONTYPE,
        )
