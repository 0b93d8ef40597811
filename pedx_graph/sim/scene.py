"""The simulated four-way-stop intersection: ground, buildings, poles, parked and moving cars, walkways.

Sim frame = the simulator's own LiDAR frame of the stopped capture vehicle, before ``output_T_sim`` (x forward,
y left, +z against gravity, metres; the ground is the plane ``z = ground_z = -lidar.height_m``).  The vehicle
waits at the stop line of the approach from -x; the intersection centre is at ``(intersection_x_m,
road_center_y_m)``.  The approach road and the far road run along x, the cross road along y.

Every solid is a triangle mesh ``(vertices (V, 3), faces (F, 3))`` tagged with an integer *object id*
(:class:`SceneObject`); ray casting (:class:`RayScene`, Embree through ``embreex``) reports the object id of
the first surface hit, which is the simulator's ground truth for LiDAR point membership and visibility.
The capture vehicle itself is not modelled (its own returns are what ``lidar.min_range_m`` removes).
"""
from __future__ import annotations

import functools
import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from pedx_graph.sim.config import SimConfig

logger = logging.getLogger(__name__)

#: Object ids: the ground is always 0; other objects are numbered in creation order.
GROUND_ID = 0


@dataclass(frozen=True)
class SceneObject:
    """One solid of the scene (static, or a moving car / pedestrian whose mesh changes per frame)."""

    object_id: int
    """Integer id reported by ray casting (0 = ground)."""
    kind: str
    """``ground``, ``building``, ``pole``, ``parked_car``, ``moving_car`` or ``pedestrian``."""
    name: str
    """Readable name (for pedestrians: the tracking id)."""


@dataclass(frozen=True)
class Walkway:
    """A straight strip people walk along: a crosswalk or a sidewalk (world xy, metres)."""

    name: str
    """E.g. ``crosswalk-near`` or ``sidewalk-x+y+``."""
    kind: str
    """``crosswalk`` or ``sidewalk``."""
    start_xy: np.ndarray
    """(2,) one end of the centre line."""
    end_xy: np.ndarray
    """(2,) the other end."""
    half_width_m: float
    """Half of the strip's width."""

    @property
    def length_m(self) -> float:
        return float(np.linalg.norm(self.end_xy - self.start_xy))

    @property
    def direction(self) -> np.ndarray:
        """(2,) unit vector from start to end."""
        return (self.end_xy - self.start_xy) / self.length_m


@dataclass
class MovingCar:
    """A car driving straight at constant speed: ``world_xy(t) = start_xy + t * speed * (cos yaw, sin yaw)``."""

    object_id: int
    start_xy: np.ndarray
    """(2,) position at t = 0 (centre of the footprint), metres."""
    yaw_rad: float
    """Heading about world z (0 = +x)."""
    speed_mps: float
    """Speed, m/s."""
    car_vertices: np.ndarray
    """(V, 3) mesh in the car frame (x forward, y left, +z against gravity from the ground at the footprint centre)."""
    faces: np.ndarray
    """(F, 3) triangle indices."""

    @property
    def heading(self) -> np.ndarray:
        """(2,) unit vector of the driving direction in world xy."""
        return np.array([np.cos(self.yaw_rad), np.sin(self.yaw_rad)])

    def world_vertices(self, time_s: float, ground_z: float) -> np.ndarray:
        """(V, 3) world vertices at ``time_s`` seconds."""
        xy = self.start_xy + time_s * self.speed_mps * self.heading
        return _place(self.car_vertices, xy, self.yaw_rad, ground_z)


@dataclass
class StaticScene:
    """The intersection: static meshes, moving cars, walkways and the object table."""

    ground_z: float
    """z of the ground plane in the world frame (= -LiDAR height)."""
    objects: list[SceneObject]
    """Every object (static, moving cars; pedestrians are appended by the simulator)."""
    static_meshes: list[tuple[int, np.ndarray, np.ndarray]]
    """(object id, world vertices (V, 3), faces (F, 3)) of the ground, buildings, poles and parked cars."""
    moving_cars: list[MovingCar]
    """Cars crossing the intersection."""
    walkways: list[Walkway]
    """Crosswalks and sidewalks."""
    car_footprints: list[np.ndarray] = field(default_factory=list)
    """(4, 2) world xy corners of every parked car (for overlap checks)."""

    def meshes_at(self, time_s: float) -> list[tuple[int, np.ndarray, np.ndarray]]:
        """Static meshes plus the moving cars placed at ``time_s``."""
        out = list(self.static_meshes)
        for car in self.moving_cars:
            out.append((car.object_id, car.world_vertices(time_s, self.ground_z), car.faces))
        return out

    def add_object(self, kind: str, name: str) -> int:
        """Append an object to the table and return its id."""
        object_id = len(self.objects)
        self.objects.append(SceneObject(object_id, kind, name))
        return object_id

    def object_table(self) -> list[dict]:
        """JSON-ready list of ``{"id", "kind", "name"}``."""
        return [{"id": o.object_id, "kind": o.kind, "name": o.name} for o in self.objects]


def _rot_z(yaw_rad: float) -> np.ndarray:
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _place(local_vertices: np.ndarray, xy: np.ndarray, yaw_rad: float, ground_z: float) -> np.ndarray:
    """Rotate (V, 3) local vertices by ``yaw`` about z and move them to ``(x, y, ground_z)``."""
    return local_vertices @ _rot_z(yaw_rad).T + np.array([xy[0], xy[1], ground_z])


def _box(extents, center) -> tuple[np.ndarray, np.ndarray]:
    mesh = trimesh.creation.box(extents=extents)
    return np.asarray(mesh.vertices) + np.asarray(center, dtype=float), np.asarray(mesh.faces)


def _merge(parts: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    verts, faces, offset = [], [], 0
    for v, f in parts:
        verts.append(v)
        faces.append(f + offset)
        offset += len(v)
    return np.concatenate(verts).astype(float), np.concatenate(faces).astype(np.int64)


def car_mesh(length_m: float, width_m: float, height_m: float) -> tuple[np.ndarray, np.ndarray]:
    """A box-ish car in its own frame (x forward, y left, +z against gravity, ground at z = 0): body, cabin, 4 wheels.

    Returns ``(vertices (V, 3), faces (F, 3))``; a few hundred triangles.
    """
    wheel_r = 0.32
    body_h = 0.55 * height_m
    parts = [
        _box((length_m, width_m, body_h), (0.0, 0.0, 0.28 + body_h / 2)),
        _box((0.55 * length_m, 0.9 * width_m, height_m - 0.28 - body_h),
             (-0.05 * length_m, 0.0, 0.28 + body_h + (height_m - 0.28 - body_h) / 2)),
    ]
    wheel = trimesh.creation.cylinder(radius=wheel_r, height=0.22, sections=16)
    wheel.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    for sx in (-1, 1):
        for sy in (-1, 1):
            parts.append((np.asarray(wheel.vertices) + [sx * 0.33 * length_m, sy * (width_m / 2 - 0.11), wheel_r],
                          np.asarray(wheel.faces)))
    return _merge(parts)


def pole_mesh(height_m: float = 2.3) -> tuple[np.ndarray, np.ndarray]:
    """A stop-sign pole with an octagonal plate facing local +x (ground at z = 0)."""
    pole = trimesh.creation.cylinder(radius=0.04, height=height_m, sections=8)
    plate = trimesh.creation.cylinder(radius=0.38, height=0.02, sections=8)
    plate.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    return _merge([(np.asarray(pole.vertices) + [0, 0, height_m / 2], np.asarray(pole.faces)),
                   (np.asarray(plate.vertices) + [0.05, 0, height_m - 0.2], np.asarray(plate.faces))])


def make_walkways(config: SimConfig) -> list[Walkway]:
    """The four crosswalks and eight sidewalks of the intersection (world xy)."""
    sc = config.scene
    cx, cy, w = sc.intersection_x_m, sc.road_center_y_m, sc.road_half_width_m
    cw, sw, ext = sc.crosswalk_width_m, sc.sidewalk_width_m, sc.walkway_extent_m
    a = np.array
    out = [
        # crosswalks across the approach/far roads (run along y) and across the cross road (run along x);
        # each extends over the sidewalks at both ends so people step on and off.
        Walkway("crosswalk-near", "crosswalk", a([cx - w - cw / 2, cy - w - sw]), a([cx - w - cw / 2, cy + w + sw]), cw / 2),
        Walkway("crosswalk-far", "crosswalk", a([cx + w + cw / 2, cy - w - sw]), a([cx + w + cw / 2, cy + w + sw]), cw / 2),
        Walkway("crosswalk-right", "crosswalk", a([cx - w - sw, cy - w - cw / 2]), a([cx + w + sw, cy - w - cw / 2]), cw / 2),
        Walkway("crosswalk-left", "crosswalk", a([cx - w - sw, cy + w + cw / 2]), a([cx + w + sw, cy + w + cw / 2]), cw / 2),
    ]
    for side in (-1, 1):
        for end in (-1, 1):
            tag = f"{'+' if side > 0 else '-'}{'+' if end > 0 else '-'}"
            # sidewalks along the x-running roads, at y = cy +- (w + sw/2)
            out.append(Walkway(f"sidewalk-x{tag}", "sidewalk",
                               a([cx + end * w, cy + side * (w + sw / 2)]),
                               a([cx + end * ext, cy + side * (w + sw / 2)]), sw / 2))
            # sidewalks along the cross road, at x = cx +- (w + sw/2)
            out.append(Walkway(f"sidewalk-y{tag}", "sidewalk",
                               a([cx + side * (w + sw / 2), cy + end * w]),
                               a([cx + side * (w + sw / 2), cy + end * ext]), sw / 2))
    return out


def _footprint(xy: np.ndarray, yaw: float, length: float, width: float) -> np.ndarray:
    corners = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]]) * [length / 2, width / 2]
    return corners @ _rot_z(yaw)[:2, :2].T + xy


def _overlaps(fp: np.ndarray, others: list[np.ndarray], margin: float) -> bool:
    lo, hi = fp.min(0) - margin, fp.max(0) + margin
    return any(np.all(lo <= o.max(0)) and np.all(o.min(0) <= hi) for o in others)


def build_scene(config: SimConfig, rng: np.random.Generator) -> StaticScene:
    """Build the intersection for ``config`` (randomised car and building placement from ``rng``)."""
    sc = config.scene
    cx, cy, w = sc.intersection_x_m, sc.road_center_y_m, sc.road_half_width_m
    sw = sc.sidewalk_width_m
    ground_z = -config.lidar.height_m
    scene = StaticScene(ground_z=ground_z, objects=[], static_meshes=[], moving_cars=[],
                        walkways=make_walkways(config))

    # Ground: one large quad (Embree handles big triangles exactly).
    gid = scene.add_object("ground", "ground")
    half = 150.0
    ground_v = np.array([[cx - half, cy - half, ground_z], [cx + half, cy - half, ground_z],
                         [cx + half, cy + half, ground_z], [cx - half, cy + half, ground_z]])
    scene.static_meshes.append((gid, ground_v, np.array([[0, 1, 2], [0, 2, 3]])))

    # Buildings: blocks set back behind the sidewalks at each corner, alternating along the two roads.
    setback = w + sw + 0.5
    for sx in (-1, 1):
        for sy in (-1, 1):
            along = [0.0, 0.0]   # distance used so far along the x road / the y road
            for k in range(sc.n_buildings_per_corner):
                axis = k % 2
                size_along = rng.uniform(10.0, 20.0)
                depth = rng.uniform(8.0, 14.0)
                height = rng.uniform(5.0, 15.0)
                start = setback + along[axis]
                gap = rng.uniform(2.0, 6.0)
                along[axis] += size_along + gap
                # the next block along the other road starts beyond this one's depth: no overlaps
                along[1 - axis] = max(along[1 - axis], depth + gap)
                if axis == 0:     # along the x-running road
                    ex, ey = size_along, depth
                    center = (cx + sx * (start + size_along / 2), cy + sy * (setback + depth / 2))
                else:
                    ex, ey = depth, size_along
                    center = (cx + sx * (setback + depth / 2), cy + sy * (start + size_along / 2))
                v, f = _box((ex, ey, height), (center[0], center[1], ground_z + height / 2))
                bid = scene.add_object("building", f"building-{'+' if sx > 0 else '-'}{'+' if sy > 0 else '-'}-{k}")
                scene.static_meshes.append((bid, v, f))

    # Stop-sign poles at the four kerb corners, plates facing the approaching traffic.
    pv, pf = pole_mesh()
    for sx, sy, yaw in ((-1, -1, np.pi), (1, 1, 0.0), (1, -1, -np.pi / 2), (-1, 1, np.pi / 2)):
        xy = np.array([cx + sx * (w + 0.4), cy + sy * (w + 0.4)])
        pid = scene.add_object("pole", f"stop-sign-{'+' if sx > 0 else '-'}{'+' if sy > 0 else '-'}")
        scene.static_meshes.append((pid, _place(pv, xy, yaw, ground_z), pf))

    # Parked cars along the kerbs, away from the intersection and not in the capture vehicle's lane.
    slots = []
    for road in ("approach", "far", "cross-", "cross+"):
        for side in (-1, 1):
            if road == "approach" and side < 0:
                continue
            slots.append((road, side))
    n_tries = 0
    while len(scene.car_footprints) < sc.n_parked_cars and n_tries < 50 * max(sc.n_parked_cars, 1):
        n_tries += 1
        road, side = slots[int(rng.integers(len(slots)))]
        length, width = rng.uniform(4.2, 4.9), rng.uniform(1.75, 1.9)
        offset = rng.uniform(w + 4.0, 40.0)
        lateral = side * (w - width / 2 - 0.2)
        if road == "approach":
            xy, yaw = np.array([cx - offset, cy + lateral]), 0.0
        elif road == "far":
            xy, yaw = np.array([cx + offset, cy + lateral]), np.pi
        elif road == "cross-":
            xy, yaw = np.array([cx + lateral, cy - offset]), np.pi / 2
        else:
            xy, yaw = np.array([cx + lateral, cy + offset]), -np.pi / 2
        fp = _footprint(xy, yaw, length, width)
        if _overlaps(fp, scene.car_footprints, margin=1.0) or np.hypot(*xy) < 6.0:
            continue
        v, f = car_mesh(length, width, rng.uniform(1.4, 1.9))
        oid = scene.add_object("parked_car", f"parked-car-{len(scene.car_footprints)}")
        scene.static_meshes.append((oid, _place(v, xy, yaw, ground_z), f))
        scene.car_footprints.append(fp)

    # Moving cars on the cross road, driving through the intersection during the sequence.
    duration = sc.n_frames / sc.fps
    for k in range(sc.n_moving_cars):
        direction = 1 if rng.random() < 0.5 else -1          # +y or -y
        speed = rng.uniform(2.0, 7.0)
        lane_x = cx - direction * 1.75                         # right-hand traffic
        mid_y = cy + rng.uniform(-w, w)                        # where the car is half-way through
        start = np.array([lane_x, mid_y - direction * speed * duration / 2])
        v, f = car_mesh(rng.uniform(4.2, 4.9), rng.uniform(1.75, 1.9), rng.uniform(1.4, 1.9))
        oid = scene.add_object("moving_car", f"moving-car-{k}")
        scene.moving_cars.append(MovingCar(oid, start, direction * np.pi / 2, speed, v, f))
    return scene


def car_gaps(car: MovingCar, pelvis_xy: np.ndarray, fps: float, shift_s: float = 0.0) -> np.ndarray:
    """(P, F) horizontal distance from each pelvis ``pelvis_xy`` (P, F, 2, world xy at the frames, times
    ``k / fps``) to ``car``'s footprint (the car mesh's extent in its own frame, a rectangle) at that frame,
    with the car's drive shifted by ``shift_s`` seconds; 0 inside the footprint, metres."""
    heading = car.heading
    left = np.array([-heading[1], heading[0]])
    lo, hi = car.car_vertices[:, :2].min(axis=0), car.car_vertices[:, :2].max(axis=0)
    rel = np.asarray(pelvis_xy, dtype=float) - car.start_xy
    times = np.arange(rel.shape[1]) / float(fps)
    along = rel @ heading - car.speed_mps * (times + shift_s)[None, :]
    across = rel @ left
    beyond_along = np.maximum(np.maximum(lo[0] - along, along - hi[0]), 0.0)
    beyond_across = np.maximum(np.maximum(lo[1] - across, across - hi[1]), 0.0)
    return np.hypot(beyond_along, beyond_across)


def retime_moving_cars(scene: StaticScene, pelvis_xy: np.ndarray, present: np.ndarray, fps: float,
                       clearance_m: float, max_shift_s: float = 60.0) -> list[float]:
    """Retime ``scene.moving_cars`` in place so that none comes within ``clearance_m`` of a pedestrian.

    ``pelvis_xy`` (P, F, 2): the pedestrians' world pelvis xy at the sequence's frames (times ``k / fps``);
    ``present`` (P, F): where each is in the scene.  A car too near a present pelvis at some frame
    (:func:`car_gaps` below ``clearance_m``) is shifted in time: ``start_xy`` moved along its heading by
    ``s * speed`` with ``s`` the shift of smallest magnitude, a whole number of frame periods up to
    ``max_shift_s`` (the later crossing first at equal magnitude: a driver waits for the crosswalk to clear),
    that keeps it clear at every frame (none does: ``max_shift_s`` ahead, out of the scene).  Path, speed and
    mesh are kept; no random draw is made, so scenes without such a car are unchanged.  Returns the shift of
    each car, seconds (0 for cars left as they were)."""
    shifts = []
    if clearance_m <= 0 or not len(pelvis_xy):
        return [0.0] * len(scene.moving_cars)
    pelvis_xy = np.asarray(pelvis_xy, dtype=float)
    present = np.asarray(present, dtype=bool) & np.all(np.isfinite(pelvis_xy), axis=2)
    pelvis_xy = np.where(present[..., None], pelvis_xy, 0.0)
    for car in scene.moving_cars:
        def clear(shift: float) -> bool:
            return not np.any(present & (car_gaps(car, pelvis_xy, fps, shift) < clearance_m))

        chosen = 0.0
        if not clear(0.0):
            steps = np.arange(1, int(round(max_shift_s * fps)) + 1) / float(fps)
            candidates = [s for step in steps for s in (-step, step)]
            chosen = next((s for s in candidates if clear(s)), candidates[-1] if candidates else 0.0)
            car.start_xy = car.start_xy + chosen * car.speed_mps * car.heading
        shifts.append(float(chosen))
    return shifts


def outward_faces(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``faces`` reordered, if needed, so the mesh's signed volume is positive (normals point outwards)."""
    v = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    signed = np.einsum("ij,ij->i", v[faces[:, 0]], np.cross(v[faces[:, 1]], v[faces[:, 2]])).sum() / 6.0
    return faces if signed >= 0 else faces[:, ::-1].copy()


def front_facing(vertices: np.ndarray, faces: np.ndarray, viewpoints: np.ndarray,
                 margin_m: float = 0.02) -> np.ndarray:
    """(F,) bool: the triangle's outward side (counter-clockwise normal) faces at least one viewpoint.

    Test per viewpoint ``c``: ``n . (c - v0) > -margin * |n|`` (the margin keeps grazing triangles).
    """
    v = np.asarray(vertices, dtype=np.float64)
    v0 = v[faces[:, 0]]
    normal = np.cross(v[faces[:, 1]] - v0, v[faces[:, 2]] - v0)
    # n . (c - v0) for every viewpoint c: (F, K)
    side = normal @ np.atleast_2d(viewpoints).T - np.einsum("ij,ij->i", normal, v0)[:, None]
    return np.any(side > -margin_m * np.linalg.norm(normal, axis=1)[:, None], axis=1)


def _aligned_empty(shape, dtype, align: int = 64) -> np.ndarray:
    """An uninitialised C-contiguous array whose data pointer is ``align``-byte aligned."""
    dtype = np.dtype(dtype)
    count = int(np.prod(shape))
    raw = np.empty(count * dtype.itemsize + align, dtype=np.uint8)
    start = (-raw.ctypes.data) % align
    return raw[start:start + count * dtype.itemsize].view(dtype).reshape(shape)


class _Embree4:
    """Direct ctypes binding to the Embree 4 library that the ``embreex`` wheel ships (``embreex.libs``).

    Why: embreex copies vertex and index buffers element by element in Python-level code (~1.5 us per
    triangle, most of a frame's time); here the numpy buffers are shared with Embree
    (``rtcSetSharedGeometryBuffer``) and rays are traced in packets of 16 (``rtcIntersect16``).  Only fields
    before ``instID`` of ``RTCHit16`` are read, and every packet gets 2 KiB, more than any Embree 4 layout
    needs.  :func:`_embree4` self-tests the binding against known hits and returns None (embreex is used
    instead) when the library is missing or the test fails.
    """

    PACKET = 16
    STRIDE_WORDS = 512                  # 2 KiB per RTCRayHit16 slot (the struct is <= 1.4 KiB)
    # word offsets of RTCRay16 / RTCHit16 fields (16 lanes each)
    ORG_X, ORG_Y, ORG_Z, TNEAR, DIR_X, DIR_Y, DIR_Z, TIME, TFAR, MASK, ID, FLAGS = (16 * i for i in range(12))
    NG_X, PRIM_ID, GEOM_ID, INST_ID = 192, 272, 288, 304
    INVALID = 0xFFFFFFFF

    def __init__(self, path: str):
        import ctypes

        lib = ctypes.CDLL(path)
        vp, u32, sz = ctypes.c_void_p, ctypes.c_uint, ctypes.c_size_t
        for name, args, res in (
                ("rtcNewDevice", [ctypes.c_char_p], vp), ("rtcNewScene", [vp], vp),
                ("rtcNewGeometry", [vp, u32], vp),
                ("rtcSetSharedGeometryBuffer", [vp, u32, u32, u32, vp, sz, sz, sz], None),
                ("rtcCommitGeometry", [vp], None), ("rtcAttachGeometry", [vp, vp], u32),
                ("rtcReleaseGeometry", [vp], None), ("rtcCommitScene", [vp], None),
                ("rtcReleaseScene", [vp], None), ("rtcIntersect16", [vp, vp, vp, vp], None)):
            fn = getattr(lib, name)
            fn.argtypes, fn.restype = args, res
        self.lib = lib
        self.device = lib.rtcNewDevice(None)
        if not self.device:
            raise OSError(f"{path}: rtcNewDevice failed")
        self._valid = _aligned_empty(self.PACKET, np.int32)
        self._valid[:] = -1

    def build(self, vertices: np.ndarray, faces: np.ndarray) -> tuple[object, list]:
        """A committed scene of one triangle geometry; returns (scene handle, buffers to keep alive)."""
        lib = self.lib
        vbuf = _aligned_empty((len(vertices) + 1, 4), np.float32)   # float3 at stride 16, one pad row
        vbuf[:-1, :3] = vertices
        vbuf[:, 3] = 0.0
        vbuf[-1] = 0.0
        ibuf = _aligned_empty((len(faces), 3), np.uint32)
        ibuf[:] = faces
        scene = lib.rtcNewScene(self.device)
        geom = lib.rtcNewGeometry(self.device, 0)                         # RTC_GEOMETRY_TYPE_TRIANGLE
        lib.rtcSetSharedGeometryBuffer(geom, 1, 0, 0x9003, vbuf.ctypes.data, 0, 16, len(vertices))  # VERTEX, FLOAT3
        lib.rtcSetSharedGeometryBuffer(geom, 0, 0, 0x5003, ibuf.ctypes.data, 0, 12, len(faces))     # INDEX, UINT3
        lib.rtcCommitGeometry(geom)
        lib.rtcAttachGeometry(scene, geom)
        lib.rtcReleaseGeometry(geom)
        lib.rtcCommitScene(scene)
        return scene, [vbuf, ibuf]

    def release(self, scene) -> None:
        self.lib.rtcReleaseScene(scene)

    def intersect(self, scene, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N,) hit distance (inf = miss) and primitive id (-1 = miss) of (N, 3) float32 rays."""
        n = len(directions)
        n_packets = -(-n // self.PACKET)
        pad = n_packets * self.PACKET - n
        words = _aligned_empty((n_packets, self.STRIDE_WORDS), np.float32)
        uwords = words.view(np.uint32)

        def lanes(values: np.ndarray) -> np.ndarray:
            return np.concatenate([values, np.zeros(pad, values.dtype)]).reshape(n_packets, self.PACKET)

        for off, col in ((self.ORG_X, origins[:, 0]), (self.ORG_Y, origins[:, 1]), (self.ORG_Z, origins[:, 2]),
                         (self.DIR_X, directions[:, 0]), (self.DIR_Y, directions[:, 1]),
                         (self.DIR_Z, directions[:, 2])):
            words[:, off:off + self.PACKET] = lanes(np.asarray(col, dtype=np.float32))
        words[:, self.TNEAR:self.TNEAR + self.PACKET] = 0.0
        words[:, self.TIME:self.TIME + self.PACKET] = 0.0
        words[:, self.TFAR:self.TFAR + self.PACKET] = np.inf
        uwords[:, self.MASK:self.MASK + self.PACKET] = self.INVALID
        uwords[:, self.ID:self.ID + self.PACKET] = 0
        uwords[:, self.FLAGS:self.FLAGS + self.PACKET] = 0
        uwords[:, self.GEOM_ID:self.GEOM_ID + self.PACKET] = self.INVALID
        uwords[:, self.INST_ID:self.INST_ID + self.PACKET] = self.INVALID
        fn, valid = self.lib.rtcIntersect16, self._valid.ctypes.data
        base, stride = words.ctypes.data, self.STRIDE_WORDS * 4
        if pad:
            # the last packet's unused lanes are switched off
            last_valid = _aligned_empty(self.PACKET, np.int32)
            last_valid[:] = -1
            last_valid[self.PACKET - pad:] = 0
        for p in range(n_packets):
            fn(last_valid.ctypes.data if (pad and p == n_packets - 1) else valid, scene, base + p * stride, None)
        geom = uwords[:, self.GEOM_ID:self.GEOM_ID + self.PACKET].reshape(-1)[:n]
        hit = geom != self.INVALID
        dist = np.where(hit, words[:, self.TFAR:self.TFAR + self.PACKET].reshape(-1)[:n].astype(np.float64), np.inf)
        prim = np.where(hit, uwords[:, self.PRIM_ID:self.PRIM_ID + self.PACKET].reshape(-1)[:n].astype(np.int64), -1)
        return dist, prim



@functools.lru_cache(maxsize=1)
def _embree4() -> _Embree4 | None:
    """The ctypes Embree 4 binding if the embreex wheel's library loads and passes a self-test, else None."""
    try:
        import embreex

        libs = sorted(Path(embreex.__file__).resolve().parent.parent.glob("embreex.libs/libembree4*.so*"))
        if not libs:
            return None
        backend = _Embree4(str(libs[0]))
        # self-test: a triangle in the plane x = 5 and a box behind it; 37 rays (a partial last packet)
        tri_v = np.array([[5.0, -1.0, -1.0], [5.0, 1.0, -1.0], [5.0, 0.0, 1.0], [9.0, -9.0, -9.0],
                          [9.0, 9.0, -9.0], [9.0, 0.0, 9.0]])
        scene, keep = backend.build(tri_v, np.array([[0, 1, 2], [3, 4, 5]]))
        rng = np.random.default_rng(0)
        dirs = np.concatenate([[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], rng.normal(size=(35, 3))])
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        orig = np.zeros_like(dirs)
        dist, prim = backend.intersect(scene, orig.astype(np.float32), dirs.astype(np.float32))
        backend.release(scene)
        del keep
        # reference: analytic ray-triangle intersection (Moller-Trumbore)
        ref_d, ref_p = np.full(len(dirs), np.inf), np.full(len(dirs), -1)
        for f, (a, b, c) in enumerate(tri_v.reshape(2, 3, 3)):
            e1, e2 = b - a, c - a
            pvec = np.cross(dirs, e2)
            det = pvec @ e1
            with np.errstate(divide="ignore", invalid="ignore"):
                u = ((orig - a) * pvec).sum(1) / det
                qvec = np.cross(orig - a, e1)
                v = (dirs * qvec).sum(1) / det
                t = (qvec @ e2) / det
            ok = (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0) & (t < ref_d)
            ref_d[ok], ref_p[ok] = t[ok], f
        if not (np.array_equal(prim, ref_p) and np.allclose(dist, ref_d, rtol=1e-5)
                and prim[0] == 0 and np.isclose(dist[0], 5.0) and prim[1] == -1):
            logger.warning("Embree 4 ctypes self-test failed; using embreex (slower scene builds)")
            return None
        return backend
    except Exception as exc:  # noqa: BLE001 - any failure means: use embreex
        logger.info("Embree 4 ctypes binding unavailable (%s); using embreex", exc)
        return None


class RayScene:
    """Embree ray caster over a list of tagged meshes, merged into one Embree geometry.

    ``cast(origins, directions)`` returns, per ray, the distance to the first hit along the unit direction
    (``inf`` on a miss) and the object id of the hit mesh (-1 on a miss), looked up from the hit triangle.
    (One geometry: embreex has a fixed cost of several ms per geometry.)  Embree works in float32: hit
    distances are accurate to ~1e-6 relative (sub-millimetre at 100 m).  Both backends give the same hits
    (``tests/test_sim_components.py``).
    """

    def __init__(self, meshes: list[tuple[int, np.ndarray, np.ndarray]], viewpoints: np.ndarray | None = None,
                 backend: str = "auto"):
        """``meshes``: (object id, vertices (V, 3), faces (F, 3)).  ``backend``: ``"auto"`` (the direct
        Embree 4 binding when it passes its self-test, else embreex), or ``"embreex"``.  ``viewpoints``
        (K, 3), used with embreex only: every ray will start at (or very near) one of these points, so
        triangles facing away from all of them are dropped (back-face culling: the first hit of a ray from
        outside a closed mesh is always a front face; triangles are counter-clockwise seen from outside),
        halving embreex's slow element-by-element buffer copy (~1.5 us per triangle)."""
        if backend not in ("auto", "embreex"):
            raise ValueError(f"backend must be 'auto' or 'embreex', got {backend!r}")
        self._backend = _embree4() if backend == "auto" else None
        if self._backend is not None:
            viewpoints = None          # shared buffers: culling would cost about what it saves
        verts, faces, owner, offset = [], [], [], 0
        for object_id, vertices, tri in meshes:
            if len(tri) == 0:
                continue
            tri = np.asarray(tri, dtype=np.int64)
            vertices = np.asarray(vertices)
            if viewpoints is not None and len(tri) > 64:
                tri = tri[front_facing(vertices, tri, viewpoints)]
                used = np.zeros(len(vertices), dtype=bool)   # pass only the vertices the kept triangles use
                used[tri.ravel()] = True
                tri = (np.cumsum(used) - 1)[tri]
                vertices = vertices[used]
            verts.append(np.asarray(vertices, dtype=np.float32))
            faces.append(tri + offset)
            owner.append(np.full(len(tri), object_id, dtype=np.int64))
            offset += len(vertices)
        self._face_to_object = np.concatenate(owner + [np.array([-1], dtype=np.int64)])   # index -1 -> miss
        self._empty = not verts
        self._scene = None
        if self._empty:
            return
        all_vertices = np.concatenate(verts)
        all_faces = np.concatenate(faces)
        if self._backend is not None:
            self._scene, self._buffers = self._backend.build(all_vertices, all_faces)
        else:
            try:
                from embreex import mesh_construction, rtcore_scene
            except ImportError as exc:  # pragma: no cover - embreex is a declared dependency
                raise ImportError("the simulator needs embreex (Embree ray casting): pip install embreex") from exc
            self._scene = rtcore_scene.EmbreeScene()
            mesh_construction.TriangleMesh(self._scene, np.ascontiguousarray(all_vertices, dtype=np.float32),
                                           np.ascontiguousarray(all_faces, dtype=np.int32))

    def __del__(self):
        if getattr(self, "_backend", None) is not None and getattr(self, "_scene", None) is not None:
            self._backend.release(self._scene)
            self._scene = None

    @property
    def backend(self) -> str:
        """``"embree4-ctypes"`` or ``"embreex"``."""
        return "embreex" if self._backend is None else "embree4-ctypes"

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """First hits of (N, 3) rays: ``(distance (N,), object_id (N,))``; directions must be unit."""
        directions = np.ascontiguousarray(directions, dtype=np.float32).reshape(-1, 3)
        origins = np.ascontiguousarray(np.broadcast_to(np.asarray(origins, dtype=np.float32), directions.shape))
        if len(directions) == 0 or self._empty:
            return np.full(len(directions), np.inf), np.full(len(directions), -1, dtype=np.int64)
        if self._backend is not None:
            dist, prim = self._backend.intersect(self._scene, origins, directions)
            return dist, self._face_to_object[prim]
        res = self._scene.run(origins, directions, output=1)
        prim = np.asarray(res["primID"], dtype=np.int64)
        hit = np.asarray(res["geomID"], dtype=np.int64) >= 0
        dist = np.where(hit, np.asarray(res["tfar"], dtype=np.float64), np.inf)
        return dist, self._face_to_object[np.where(hit, prim, -1)]
