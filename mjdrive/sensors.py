"""Sensors read from the simulation and the road map: collision, lane invasion, route progress, cameras.

All of them look ids up once at construction and do numpy work per step (no name look-ups, no Python
loops over contacts, vehicles or lanes).
"""

from __future__ import annotations

import atexit
import os
import weakref
from typing import Any

import mujoco
import numpy as np

from mjdrive.roads import RoadMap


class CollisionSensor:
    """Flags any contact between an ego geom and a geom that is not the ground (the road surface).

    A bump can bounce off within one control step (0.2 s at 5 Hz: a car hitting a stopped motorcycle at
    2 m/s touched it for 0.08 s), so a task samples the contacts between physics chunks (`sample`) and
    reads `collided` once per control step: a contact at any sample or now counts."""

    def __init__(self, model: mujoco.MjModel, prefix: str = "ego/", ground: str = "ground"):
        root = model.body(prefix + "chassis").id
        ego_body = model.body_rootid == root
        # per geom: 1 the ego's, 2 anything else it can hit, 0 the ground; a pair collides iff its product is 2
        self.code = np.where(ego_body[model.geom_bodyid], 1, 2).astype(np.int8)
        self.code[model.geom(ground).id] = 0
        self.last_other_geom = -1  # geom id the ego touched last, for logs
        self.pending = False  # a contact was sampled since the last `collided`
        # the world's contact sensors (`world.add_contact_sensors`): the ego's contacts, those with the ground
        names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_SENSOR, i) for i in range(model.nsensor)]
        found = [f"{prefix}contacts" in names, f"{prefix}ground_contacts" in names]
        self._counts = (int(model.sensor_adr[names.index(f"{prefix}contacts")]),
                        int(model.sensor_adr[names.index(f"{prefix}ground_contacts")])) if all(found) else None

    def __call__(self, data: mujoco.MjData) -> bool:
        """Whether the ego touches another geom now."""
        if self._counts is not None:  # the sensors tell whether there is any; the contacts, which one
            counts = data.sensordata
            if counts[self._counts[0]] <= counts[self._counts[1]]:
                return False
        elif data.ncon == 0:
            return False
        pairs = data.contact.geom  # (ncon, 2)
        codes = self.code[pairs]
        hit = codes[:, 0] * codes[:, 1] == 2
        if not hit.any():
            return False
        k = int(np.argmax(hit))
        self.last_other_geom = int(pairs[k, 1] if codes[k, 0] == 1 else pairs[k, 0])
        return True

    @property
    def contact_sensors(self) -> tuple[int, int] | None:
        """sensordata addresses of the world's counts of the ego's contacts and of its contacts with the ground
        (touching something else iff the first exceeds the second); None if the world has no such sensors."""
        return self._counts

    def sample(self, data: mujoco.MjData) -> None:
        """Check the contacts now and remember a hit until the next `collided`."""
        if not self.pending and self(data):
            self.pending = True

    def collided(self, data: mujoco.MjData) -> bool:
        """Whether the ego touched another geom at a sample since the last call, or touches one now."""
        hit = self.pending or self(data)
        self.pending = False
        return hit

    def reset(self) -> None:
        self.last_other_geom = -1
        self.pending = False


class LaneInvasionSensor:
    """Flags a crossing of a SOLID marking by any corner of the ego footprint since the previous call."""

    def __init__(self, road_map: RoadMap):
        self.road_map = road_map
        self.previous: np.ndarray | None = None
        self.previous_inside = False

    def reset(self, corners: np.ndarray) -> None:
        self.previous = corners.copy()
        self.previous_inside = False

    def __call__(self, corners: np.ndarray, inside_lane: bool = False) -> bool:
        """`inside_lane`: the caller knows the footprint lies wholly inside one lane strip now; if it also
        did at the previous call, no marking can have been crossed and the map query is skipped."""
        if inside_lane and self.previous_inside:
            crossed = False
        else:
            crossed = self.previous is not None and bool(self.road_map.crossed_solid(self.previous, corners))
        self.previous, self.previous_inside = corners, inside_lane
        return crossed


class RouteTracker:
    """Waypoints along a route: which is next, which were reached (within `reach_radius`), completion.

    A waypoint counts as reached when the ego comes within `reach_radius` [m] of it (the study's W); a
    waypoint the ego passes farther away (its projection overtakes it) is skipped, not reached.
    """

    def __init__(self, points: np.ndarray, headings: np.ndarray, reach_radius: float = 3.0):
        self.points = np.asarray(points, float)  # (M,2) [m]
        self.headings = np.asarray(headings, float)  # (M,) [rad]
        self.reach_radius = reach_radius
        self.next_index = 0
        self.reached = 0

    @property
    def total(self) -> int:
        return len(self.points)

    @property
    def done(self) -> bool:
        return self.next_index >= self.total

    @property
    def completion(self) -> float:
        """Share of the route's waypoints reached, in [0, 1]."""
        return self.reached / self.total

    def update(self, xy: np.ndarray) -> bool:
        """Advance past reached or overtaken waypoints; True if at least one was reached (W)."""
        reached_any = False
        while self.next_index < self.total:
            delta = self.points[self.next_index] - xy
            if delta @ delta <= self.reach_radius**2:
                self.reached += 1
                reached_any = True
            else:
                h = self.headings[self.next_index]
                if delta[0] * np.cos(h) + delta[1] * np.sin(h) > 0.0:  # still ahead of the ego
                    break
            self.next_index += 1
        return reached_any

    def upcoming(self, count: int) -> np.ndarray:
        """The next `count` waypoints (count,2), padded with the last one past the end of the route."""
        idx = np.minimum(np.arange(self.next_index, self.next_index + count), self.total - 1)
        return self.points[idx]


_OPEN_RENDERERS: weakref.WeakSet = weakref.WeakSet()
# Each open renderer's (GL context, MuJoCo render context), by id(renderer): held here so that neither is
# garbage-collected on its own (their finalizers would free GL objects in whichever context is current, i.e.
# another renderer's); only CameraRenderer.close frees them, with their own context current.
_CONTEXTS: dict[int, tuple[Any, mujoco.MjrContext]] = {}
FONT_SCALE = mujoco.mjtFontScale.mjFONTSCALE_150  # mujoco.Renderer's default
MAX_GEOMS = 10_000  # geoms a scene holds (mujoco.Renderer's default)


def _gl_context_class() -> type:
    """MuJoCo's off-screen GL context class for MUJOCO_GL (read when mujoco was first imported). If mujoco was
    imported before mjdrive (so before MUJOCO_GL defaulted to egl) on a machine without a display, it picked
    GLFW, which cannot open a context: EGL or OSMesa then, without changing mujoco's own choice."""
    from mujoco.rendering.classic import gl_context

    context_class = getattr(gl_context, "GLContext", None)
    if context_class is None:
        raise RuntimeError(f"off-screen rendering is disabled (MUJOCO_GL={os.environ.get('MUJOCO_GL')!r} when "
                           "mujoco was imported); set MUJOCO_GL=egl or osmesa before importing mujoco")
    if context_class.__module__.startswith("mujoco.glfw") and not os.environ.get("DISPLAY"):
        if os.environ.get("MUJOCO_GL", "egl").lower() == "osmesa":
            from mujoco.osmesa import GLContext
        else:
            from mujoco.egl import GLContext
        context_class = GLContext
    return context_class


def _close_renderers() -> None:
    """Free every open renderer's GL context before the GL library itself is torn down at exit (avoids EGL
    errors); registered after the GL backend's own exit handler, so it runs first."""
    for renderer in list(_OPEN_RENDERERS):
        renderer.close()


class CameraRenderer:
    """Off-screen RGB camera with shadows, reflections and (by default) anti-aliasing off, and optional
    waypoint markers.

    Each renderer owns its GL context: it makes it current before every render and before freeing its GL
    objects, so any number of renderers (of one env or of several) can be made and closed in any order without
    touching each other's images. Markers are drawn into the scene at render time only (they do not exist in
    the physics).
    """

    MARKER_RGBA = np.array([0.1, 0.9, 0.2, 1.0], np.float32)
    MARKER_SIZE = np.array([0.35, 0.35, 0.02])  # [m] half sizes of the flat green rectangles

    def __init__(self, model: mujoco.MjModel, camera: str, height: int, width: int, antialias: bool = False,
                 flat_planes: bool = False):
        """`flat_planes`: draw each infinite plane (the ground) as 4 quads instead of MuJoCo's 200x200 grid,
        which exists for per-vertex lighting and costs most of a small software render; for unlit renders
        (segmentation and depth), where the grid changes nothing but float rounding."""
        cameras = [model.camera(i).name for i in range(model.ncam)]
        if camera not in cameras:
            raise ValueError(f"no camera {camera!r} in the model; cameras: {', '.join(cameras)}")
        if not (0 < width <= model.vis.global_.offwidth and 0 < height <= model.vis.global_.offheight):
            raise ValueError(f"image size {height}x{width} px must be positive and at most the model's off-screen "
                             f"buffer, {model.vis.global_.offheight}x{model.vis.global_.offwidth} px")
        self.model, self.camera_id = model, model.camera(camera).id
        self.height, self.width = height, width
        gl = _gl_context_class()(width, height)
        samples = model.vis.quality.offsamples
        # Multisampling triples the cost of a small software render: off for observations, on for videos.
        model.vis.quality.offsamples = samples if antialias else 0
        planes = np.flatnonzero((model.geom_type == mujoco.mjtGeom.mjGEOM_PLANE)
                                & (model.geom_size[:, :2] <= 0).any(axis=1)) if flat_planes else []
        plane_sizes = model.geom_size[planes].copy()
        # The context builds each plane's display list from its size: a finite plane larger than the far clip
        # plane (scenes keep infinite planes centred on the camera), one grid cell per half size.
        model.geom_size[planes] = 1.1 * model.vis.map.zfar * model.stat.extent  # [m]
        try:
            gl.make_current()
            context = mujoco.MjrContext(model, FONT_SCALE.value)
            mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN.value, context)
        except (mujoco.FatalError, RuntimeError) as error:
            gl.free()
            raise RuntimeError(
                f"off-screen rendering failed ({error}). Install libegl1 libopengl0 libgl1-mesa-dri "
                "(MUJOCO_GL=egl) or libosmesa6 (MUJOCO_GL=osmesa), e.g. with `make install` as root."
            ) from error
        finally:
            model.vis.quality.offsamples = samples
            model.geom_size[planes] = plane_sizes
        if not _OPEN_RENDERERS:  # registered after the GL backend's own exit handler, so it runs first
            atexit.unregister(_close_renderers)
            atexit.register(_close_renderers)
        _CONTEXTS[id(self)] = (gl, context)
        _OPEN_RENDERERS.add(self)
        self.scene = mujoco.MjvScene(model, maxgeom=MAX_GEOMS)
        self.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
        self.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
        self.scene.flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = True
        self.option = mujoco.MjvOption()
        self.view = mujoco.MjvCamera()
        self.view.type, self.view.fixedcamid = mujoco.mjtCamera.mjCAMERA_FIXED, self.camera_id
        self.rect = mujoco.MjrRect(0, 0, width, height)
        self._pixels = np.empty((height, width, 3), np.uint8)  # as GL reads them: bottom row first
        self.buffer = np.empty((height, width, 3), np.uint8)
        self._identity = np.eye(3).ravel()

    @property
    def closed(self) -> bool:
        return id(self) not in _CONTEXTS

    def _update_scene(self, data: mujoco.MjData) -> None:
        mujoco.mjv_updateScene(self.model, data, self.option, None, self.view, mujoco.mjtCatBit.mjCAT_ALL.value,
                               self.scene)

    def render(self, data: mujoco.MjData, markers: np.ndarray | None = None, z: float = 0.03) -> np.ndarray:
        """Render into the reused buffer; returns it (copy it if you keep it). RuntimeError after `close`."""
        if self.closed:
            raise RuntimeError("this CameraRenderer is closed (its GL context is freed); make a new one")
        gl, context = _CONTEXTS[id(self)]
        # MuJoCo places infinite planes (the ground) using the camera pose of the *previous* scene update,
        # so a frame after the camera jumped (a reset) would differ from the same state rendered again:
        # update twice (a few µs) so the image depends on the state alone.
        self._update_scene(data)
        self._update_scene(data)
        scene = self.scene
        if markers is not None:
            for point in markers:
                if scene.ngeom >= scene.maxgeom:
                    break
                mujoco.mjv_initGeom(
                    scene.geoms[scene.ngeom], mujoco.mjtGeom.mjGEOM_BOX, self.MARKER_SIZE,
                    np.array([point[0], point[1], z]), self._identity, self.MARKER_RGBA,
                )
                scene.ngeom += 1
        gl.make_current()  # this renderer's context: another renderer may have made its own current since
        mujoco.mjr_render(self.rect, scene, context)
        mujoco.mjr_readPixels(self._pixels, None, self.rect, context)
        np.copyto(self.buffer, self._pixels[::-1])  # GL's first row is the bottom one
        return self.buffer

    def close(self) -> None:
        """Free this renderer's GL objects with its own context current, then the context (idempotent)."""
        gl, context = _CONTEXTS.pop(id(self), (None, None))
        _OPEN_RENDERERS.discard(self)
        if gl is None:
            return
        try:
            gl.make_current()
            context.free()
            del context  # MjrContext's own finalizer runs now, with this context still current
        finally:
            gl.free()

    def __del__(self) -> None:
        if _CONTEXTS is not None and id(self) in _CONTEXTS:  # dropped without close (e.g. an env not closed)
            self.close()


# --- depth, segmentation and range: more sensors from the same renderer and model ----------------------------

SEGMENT_CLASSES = ("background", "ground", "road", "marking", "building", "ego", "car", "motorcycle", "bicycle",
                   "pedestrian", "other")  # label i of a segmentation image is SEGMENT_CLASSES[i]
_GEOM_NAME_CLASSES = {"ground": "ground", "road_surface": "road", "road_areas": "road", "markings": "marking",
                      "crosswalks": "marking", "give_way_lines": "marking"}


def geom_classes(model: mujoco.MjModel, prefix: str = "ego/") -> np.ndarray:
    """(ngeom,) uint8 SEGMENT_CLASSES index of every geom, from the world's names (`world.build_spec`)."""
    index = {name: i for i, name in enumerate(SEGMENT_CLASSES)}
    root = model.body(prefix + "chassis").id
    out = np.full(model.ngeom, index["other"], np.uint8)
    for geom in range(model.ngeom):
        name = model.geom(geom).name or ""
        if model.body_rootid[model.geom_bodyid[geom]] == root:
            out[geom] = index["ego"]
        elif name in _GEOM_NAME_CLASSES:
            out[geom] = index[_GEOM_NAME_CLASSES[name]]
        elif name.startswith("building_"):
            out[geom] = index["building"]
        elif name.startswith("traffic_"):
            out[geom] = index.get(name.rsplit("_", 1)[-1], index["other"])
    return out


class DepthSegmentationCamera(CameraRenderer):
    """A camera that reads depth [m] and a segmentation image (one SEGMENT_CLASSES index per pixel) from one
    render: MuJoCo's segmentation mode (flat colours, no lights or textures) writes the same depth buffer as
    a shaded render, so both come from a single `mjr_render` and a single `mjr_readPixels`; the ground is
    drawn as a few quads (`flat_planes`). Sky and anything beyond the far clip plane read as `far` [m] and
    class background."""

    def __init__(self, model: mujoco.MjModel, camera: str, height: int, width: int):
        super().__init__(model, camera, height, width, flat_planes=True)
        extent = model.stat.extent
        self.near, self.far = model.vis.map.znear * extent, model.vis.map.zfar * extent  # [m]
        self._depth = np.empty((height, width), np.float32)  # GL's [0, 1], bottom row first
        self._ids = np.empty((height, width), np.uint16)  # scene geom index + 1 (0: nothing drawn)
        self.classes = geom_classes(model)
        self.depth_image = np.empty((height, width), np.float32)  # [m]
        self.segmentation_image = np.empty((height, width), np.uint8)

    def render_sensors(self, data: mujoco.MjData, depth: bool = True, segmentation: bool = True) -> None:
        """Fill `depth_image` (H, W) [m] and/or `segmentation_image` (H, W) class indices for `data`."""
        if self.closed:
            raise RuntimeError("this DepthSegmentationCamera is closed; make a new one")
        gl, context = _CONTEXTS[id(self)]
        self._update_scene(data)  # twice, as CameraRenderer.render: the image depends on the state alone
        self._update_scene(data)
        flags = self.scene.flags
        flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = True
        try:
            gl.make_current()
            mujoco.mjr_render(self.rect, self.scene, context)
            mujoco.mjr_readPixels(self._pixels if segmentation else None, self._depth if depth else None,
                                  self.rect, context)
        finally:  # `render` stays a shaded RGB render
            flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = False
        if depth:
            # GL's depth in [0, 1] is hyperbolic in the distance along the view axis: back to metres, in float32
            z = self._depth
            np.multiply(z, np.float32(self.near / self.far - 1.0), out=z)
            z += np.float32(1.0)
            np.divide(np.float32(self.near), z, out=z)
            np.minimum(z[::-1], np.float32(self.far), out=self.depth_image)
        if segmentation:
            # IDCOLOR writes scene geom index + 1 as 24-bit RGB; a scene holds at most MAX_GEOMS < 2**16 geoms
            ids = self._ids
            np.left_shift(self._pixels[..., 1], 8, out=ids, dtype=np.uint16)
            ids |= self._pixels[..., 0]
            np.take(self._scene_classes(), ids[::-1], out=self.segmentation_image, mode="clip")

    def _scene_classes(self) -> np.ndarray:
        """(ngeom + 1,) class of each scene geom index + 1 (0: background); decorations that are not model
        geoms are background."""
        geoms = self.scene.geoms[: self.scene.ngeom]
        lookup = np.zeros(len(geoms) + 1, np.uint8)
        geom_type = int(mujoco.mjtObj.mjOBJ_GEOM)
        for geom in geoms:
            if geom.objtype == geom_type and geom.segid >= 0:
                lookup[geom.segid + 1] = self.classes[geom.objid]
        return lookup


class RangeRing:
    """A lidar-like ring of `rays` horizontal range readings [m] around the ego, `height` [m] above its
    chassis origin, first ray straight ahead, counter-clockwise; `max_range` where nothing is hit. Rays
    see geom group 0 (road users, buildings, the world), not the ego's own geoms (groups 1 and 3)."""

    GEOM_GROUPS = np.array([1, 0, 0, 0, 0, 0], np.uint8)

    def __init__(self, model: mujoco.MjModel, rays: int = 36, max_range: float = 50.0, height: float = 0.6,
                 body: str = "ego/chassis"):
        if rays < 1 or not max_range > 0:
            raise ValueError(f"a range ring needs rays >= 1 and max_range > 0, got {rays} and {max_range}")
        self.model, self.body = model, model.body(body).id
        self.rays, self.max_range, self.height = rays, float(max_range), float(height)
        self.angles = 2 * np.pi * np.arange(rays) / rays  # [rad] in the ego frame
        self._geomid = np.zeros(rays, np.int32)
        self._dist = np.zeros(rays, np.float64)
        self.ranges = np.zeros(rays, np.float32)

    def __call__(self, data: mujoco.MjData) -> np.ndarray:
        """(rays,) ranges [m] (the reused buffer: copy it to keep it)."""
        origin = data.xpos[self.body] + np.array([0.0, 0.0, self.height])
        xmat = data.xmat[self.body]
        yaw = np.arctan2(xmat[3], xmat[0])
        directions = np.zeros((self.rays, 3))
        directions[:, 0], directions[:, 1] = np.cos(yaw + self.angles), np.sin(yaw + self.angles)
        mujoco.mj_multiRay(self.model, data, origin, directions.ravel(), self.GEOM_GROUPS, 1, self.body,
                           self._geomid, self._dist, None, self.rays, self.max_range)
        hit = (self._geomid >= 0) & (self._dist >= 0) & (self._dist <= self.max_range)
        np.copyto(self.ranges, np.where(hit, self._dist, self.max_range))
        return self.ranges


SENSORS = ("depth", "segmentation", "range")  # extra observations every task adds on request (`sensors=`)
SENSOR_CAMERA = "ego/front"  # the depth and segmentation images' camera


class ExtraSensors:
    """The extra observations of a task's `sensors` keyword: `depth` (size, size) float32 [m] and
    `segmentation` (size, size) uint8 (SEGMENT_CLASSES indices) from one render of the front camera, and
    `range` (rays,) float32 [m] from a RangeRing. They read the state and never change it."""

    def __init__(self, names: tuple[str, ...], size: int = 64, rays: int = 36, max_range: float = 50.0):
        unknown = [name for name in names if name not in SENSORS]
        if unknown:
            raise ValueError(f"unknown sensor {unknown[0]!r}; sensors: {', '.join(SENSORS)}")
        self.names = tuple(name for name in SENSORS if name in names)  # in SENSORS order
        self.size, self.rays, self.max_range = size, rays, float(max_range)  # [px], rays, [m]
        self._model: mujoco.MjModel | None = None
        self.camera: DepthSegmentationCamera | None = None
        self.ring: RangeRing | None = None

    def specs(self, model: mujoco.MjModel) -> dict[str, Any]:
        """dm_env BoundedArray specs of the observations, by name."""
        from dm_env import specs

        far = float(model.vis.map.zfar * model.stat.extent)  # [m]
        shape = (self.size, self.size)
        out = {"depth": specs.BoundedArray(shape, np.float32, 0.0, far, "depth"),
               "segmentation": specs.BoundedArray(shape, np.uint8, 0, len(SEGMENT_CLASSES) - 1, "segmentation"),
               "range": specs.BoundedArray((self.rays,), np.float32, 0.0, self.max_range, "range")}
        return {name: out[name] for name in self.names}

    def __call__(self, model: mujoco.MjModel, data: mujoco.MjData) -> dict[str, np.ndarray]:
        """The observations of the state in `data` (new arrays)."""
        if model is not self._model:  # first call, or a task rebuilt its model
            self.close()
            self._model = model
            if "depth" in self.names or "segmentation" in self.names:
                self.camera = DepthSegmentationCamera(model, SENSOR_CAMERA, self.size, self.size)
            if "range" in self.names:
                self.ring = RangeRing(model, self.rays, self.max_range)
        out = {}
        if self.camera is not None:
            depth, segmentation = "depth" in self.names, "segmentation" in self.names
            self.camera.render_sensors(data, depth, segmentation)
            if depth:
                out["depth"] = self.camera.depth_image.copy()
            if segmentation:
                out["segmentation"] = self.camera.segmentation_image.copy()
        if self.ring is not None:
            out["range"] = self.ring(data).copy()
        return out

    def close(self) -> None:
        """Free the camera's GL context (idempotent); a later call makes a new one."""
        if self.camera is not None:
            self.camera.close()
        self.camera = self.ring = self._model = None
