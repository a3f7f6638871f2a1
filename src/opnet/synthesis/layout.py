"""The fixed set-up of a generated dataset: the procedural bin, the camera and the world frame.

World frame: z up, origin at the centre of the top of the (un-jittered) bin floor; the ground plane
is the plane z = -``bin_wall_thickness`` on which the bin stands. Bin frame: the same, attached to
the bin (per-cycle jitter moves it on the ground: x, y and yaw). The nominal camera hangs
``camera_height`` above the world origin looking straight down; in the internal OpenCV camera frame
(x right, y down, z forward, docs/formats.md#frames) that is ``R_world_cam = diag(1, -1, -1)``.

Automatic sizes (every one can be set in :class:`SceneConfig`):
- bin floor side ``L = max(2 D, sqrt(drops * a / layers))``, ``D`` the object diameter and ``a``
  the product of its two largest extents (the area of the part lying flat): ``drops`` parts lie in
  about ``bin_layers`` layers, and the longest part fits with room to turn;
- wall height ``bin_wall_factor * D``;
- with ``bin_max_fill``, the drops' convex hulls fill at most that share of the volume inside the
  walls (:func:`bin_fill`): the automatic floor widens (its height, and so the pile's, stays sized
  to the part), or where a floor is given, the automatic walls rise;
- camera height: the smallest at which the outer rim of the walls, grown by ``view_margin``, fits
  into the smaller image side (with a working area, ``bin_area``: the bin in any yaw anywhere in it);
- a camera from a file (``camera_file``: its intrinsics and image size, any principal point; at
  ``camera_scale`` x its pixels, the same field of view): the camera moves sideways so that the
  image centre, not the optical axis, looks at the bin centre; its clip planes are used with
  ``clip: camera``, else derived as below;
- clip planes: ``clip_start`` one diameter above the wall tops (parts rarely pile higher than the
  walls; closer points are written as missing depth), ``clip_end`` past the ground plane at the
  image corners under the worst camera tilt;
- several bin models (``bin_models``): each its own tote, the camera height and clip planes those
  of the model that needs them most (the camera is one per dataset).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from dataclasses import dataclass

import numpy as np
import trimesh

from opnet.datasets.camera_file import read_camera_file
from opnet.datasets.ipa_params import IPAParameters
from opnet.geometry.camera import MAX_CLIP_END_M, Camera
from opnet.objects.model import ObjectModel
from opnet.synthesis.config import SceneConfig
from opnet.synthesis.tilt import homogeneous, inverse_pose, rotation_about, tilted, tilted_clip
from opnet.synthesis.working_volume import camera_planes

__all__ = ["R_WORLD_CAM_DOWN", "BinGeometry", "CycleLayout", "Rig", "bin_fill", "bin_geometry", "hull_volume",
           "homogeneous", "inverse_pose", "make_rig", "random_rotation", "rotation_about", "sample_layout", "tilted",
           "tilted_clip", "totes", "view_layout"]

#: R_world_cam of the nominal camera: OpenCV axes, looking down (a half-turn about x)
R_WORLD_CAM_DOWN = np.diag([1.0, -1.0, -1.0])


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """(3, 3) rotation drawn uniformly on SO(3) (normalized Gaussian quaternion)."""
    # kept inline: np.linalg.norm of a vector (BLAS dot) and along an axis round differently in the
    # last bit, and the generated datasets' bytes must not change
    w, x, y, z = (q := rng.standard_normal(4)) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])  # fmt: skip


@dataclass(frozen=True)
class BinGeometry:
    """A tote: a rectangular floor and four walls, in the bin frame (floor top centre = origin, z up).

    Attributes:
        inner: inner side of the floor along the bin's x axis, metres.
        wall_height: height of the walls above the floor top, metres.
        thickness: thickness of the floor and the walls, metres.
        inner_y: inner side along y, metres; None = ``inner`` (a square floor).
        hole_size, hole_pitch: a perforated sheet (a wire basket): square holes of ``hole_size``
            metres every ``hole_pitch`` metres through the floor and the walls, in what is
            rendered only (the physics keeps solid boxes: parts are larger than the holes);
            0 = solid.
    """

    inner: float
    wall_height: float
    thickness: float
    inner_y: float | None = None
    hole_size: float = 0.0
    hole_pitch: float = 0.0

    @property
    def sides(self) -> tuple[float, float]:
        """Inner sides (x, y) of the floor, metres."""
        return self.inner, self.inner if self.inner_y is None else self.inner_y

    @property
    def outer(self) -> float:
        """Outer side of the bin along its longer axis, metres."""
        return max(self.sides) + 2.0 * self.thickness

    def boxes(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """The five boxes as (half extents (3,), centre (3,)) in the bin frame, metres."""
        (a, b), h, t = (s / 2.0 for s in self.sides), self.wall_height, self.thickness
        floor = (np.array([a + t, b + t, t / 2]), np.array([0.0, 0.0, -t / 2]))
        walls = []
        for sx, sy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            half = np.array([t / 2 if sx else a + t, t / 2 if sy else b + t, h / 2])
            walls.append((half, np.array([sx * (a + t / 2), sy * (b + t / 2), h / 2])))
        return [floor, *walls]

    def mesh(self) -> trimesh.Trimesh:
        """The bin as one triangle mesh in the bin frame, metres (for rendering); perforated when
        ``hole_size`` > 0."""
        parts = []
        for half, centre in self.boxes():
            if self.hole_size > 0:
                parts += perforated_box(half, centre, self.hole_size, self.hole_pitch)
            else:
                parts.append(trimesh.creation.box(extents=2 * half, transform=homogeneous(np.eye(3), centre)))
        return trimesh.util.concatenate(parts)

    def inside(self, points_bin: np.ndarray) -> np.ndarray:
        """(N, 3) points in the bin frame -> (N,) bool: above the floor and within the walls."""
        p = np.asarray(points_bin, dtype=np.float64).reshape(-1, 3)
        a, b = (s / 2.0 for s in self.sides)
        return (np.abs(p[:, 0]) <= a) & (np.abs(p[:, 1]) <= b) & (p[:, 2] >= -1e-3)


def perforated_box(half: np.ndarray, centre: np.ndarray, hole: float, pitch: float) -> list[trimesh.Trimesh]:
    """A box (half extents, centre; metres) pierced through its thinnest axis by square holes of side
    ``hole`` every ``pitch`` metres: the bars between the holes, as boxes (a wire basket's sheet).
    The holes' grid is centred on the box; bars at the box's edges keep its outline."""
    thin = int(np.argmin(half))
    u, v = [k for k in range(3) if k != thin]
    bar = pitch - hole
    out = []
    for axis, other in ((u, v), (v, u)):  # bars running along `other`, spaced along `axis`
        n = int(math.floor(2 * half[axis] / pitch))
        offsets = (np.arange(n + 1) - n / 2.0) * pitch
        offsets = np.unique(np.clip(offsets, -half[axis] + bar / 2, half[axis] - bar / 2))
        for off in offsets:
            extents = 2 * np.asarray(half, dtype=np.float64)
            extents[axis] = bar
            c = np.asarray(centre, dtype=np.float64).copy()
            c[axis] += off
            out.append(trimesh.creation.box(extents=extents, transform=homogeneous(np.eye(3), c)))
    return out


@dataclass(frozen=True)
class Rig:
    """Everything fixed for a dataset: bin, camera intrinsics and nominal camera pose.

    Attributes:
        bin: the tote (with ``scene.bin_models``: the first model's; :meth:`with_bin` picks another).
        params: the ``parameter.json`` content.
        camera: the written image's camera (exactly ``params.camera()``).
        T_world_cam: (4, 4) nominal camera pose, OpenCV camera frame to world, metres.
        object_radius: metres, max distance of a mesh vertex from the model origin.
        bins: the tote of each bin model (``scene.bin_models``; ``(bin,)`` without models).
    """

    bin: BinGeometry
    params: IPAParameters
    camera: Camera
    T_world_cam: np.ndarray
    object_radius: float
    bins: tuple[BinGeometry, ...] = ()

    def with_bin(self, model: int) -> Rig:
        """The rig with bin model ``model``'s tote (the camera sized for all of them)."""
        return dataclasses.replace(self, bin=(self.bins or (self.bin,))[model])


@dataclass(frozen=True)
class CycleLayout:
    """Per-cycle poses (jittered): (4, 4) bin-to-world and OpenCV-camera-to-world transforms, the
    foreign pieces lying on the pile's floor (:mod:`opnet.synthesis.clutter`; bin frame) and the
    pose of the ground plate (None: the bin's; a tilted bin's ground stays level)."""

    T_world_bin: np.ndarray
    T_world_cam: np.ndarray
    clutter: tuple = ()
    T_world_ground: np.ndarray | None = None

    @property
    def T_cam_world(self) -> np.ndarray:
        return inverse_pose(self.T_world_cam)

    @property
    def T_bin_ground(self) -> np.ndarray:
        """The ground plate's pose in the bin frame (the identity for a level bin)."""
        if self.T_world_ground is None:
            return np.eye(4)
        return inverse_pose(self.T_world_bin) @ self.T_world_ground


def make_rig(obj: ObjectModel, drops: int, cycles: int, cfg: SceneConfig) -> Rig:
    """The dataset set-up for ``drops`` parts of ``obj`` per cycle (sizes: see the module docstring)."""
    if obj.mesh is None:
        raise ValueError(f"object {obj.name!r} has no mesh: the generator needs one to simulate and render")
    D = obj.diameter
    cfg = cfg.for_part(D)  # the settings sized to the part (the rig by D / rig_d, a small part's lengths)
    bins = totes(obj, drops, cfg)
    bin_geom, wall = bins[0], max(b.wall_height for b in bins)  # every size below: the largest bin model's

    given = scaled_camera_file(cfg) if cfg.camera_file else None
    if given is None:
        width, height = cfg.image_size
        fx = fy = cfg.resolution / (2.0 * math.tan(math.radians(cfg.fov_deg) / 2.0))
        corner_tan = math.hypot(width, height) / 2.0 / fx
    else:
        width, height, fx, fy = given.width, given.height, given.fx, given.fy
        corner_tan = max(math.hypot((u - given.cx) / fx, (v - given.cy) / fy)
                         for u in (-0.5, width - 0.5) for v in (-0.5, height - 0.5))
    tan_half_image = min(width / 2.0 / fx, height / 2.0 / fy)

    def reach(b: BinGeometry) -> float:  # how far from the view's centre the bin's rim may lie
        if cfg.bin_area is None:
            return b.outer / 2.0
        # the bin in any yaw (its half diagonal) wherever the area lets it stand
        return max(map(abs, cfg.bin_area)) + math.hypot(*(side / 2.0 + b.thickness for side in b.sides))

    h = cfg.camera_height or max(b.wall_height + reach(b) * (1.0 + cfg.view_margin) / tan_half_image for b in bins)
    _check_jitter(cfg, h, wall, math.degrees(math.atan(tan_half_image)))
    tilt = math.tan(math.radians(cfg.camera_jitter_deg))
    # a tilted bin's rim rises up to outer x sin(tilt)
    near, far = camera_planes(cfg.clip, given)  # metres where given or the camera file's; None: derived below
    clip_start = near or min(
        max(h - b.wall_height - D - cfg.camera_jitter_m - b.outer * math.sin(math.radians(cfg.bin_tilt_deg)), 0.1 * h)
        for b in bins)
    clip_end = far or max((h + b.thickness) * (1.0 + tilt * corner_tan) * 1.02 + cfg.camera_jitter_m for b in bins)
    if clip_start >= clip_end:
        raise ValueError(f"scene config: clip_start={clip_start} must be below clip_end={clip_end}")

    if given is None:
        off_x, off_y = (cfg.resolution - width) // 2, (cfg.resolution - height) // 2
        params = IPAParameters(
            perspective_angle=float(cfg.fov_deg),
            clip_start=float(clip_start),
            clip_end=float(clip_end),
            resolution_x=width,
            resolution_y=height,
            resolution_big=cfg.resolution,
            pixel_offset_x=off_x,
            pixel_offset_y=off_y,
            number_cycles=int(cycles),
            shape_drop_limit=int(drops),
            location=(0.0, 0.0, float(h)),
            rotation=(0.0, 1.0, 0.0, 0.0),  # w, x, y, z of R_WORLD_CAM_DOWN
        )
    else:
        # the camera moves so that the image centre (not the optical axis) looks at the bin centre:
        # an off-centre principal point still sees the whole bin
        sx = -h * ((width - 1) / 2.0 - given.cx) / fx
        sy = h * ((height - 1) / 2.0 - given.cy) / fy  # image y runs along -world y
        camera = Camera(fx, fy, given.cx, given.cy, width, height, float(clip_start), float(clip_end))
        params = IPAParameters.for_any_camera(camera, int(cycles), int(drops), location=(sx, sy, float(h)),
                                              rotation=(0.0, 1.0, 0.0, 0.0))
    location = np.array(params.location)
    radius = float(np.linalg.norm(obj.mesh.vertices, axis=1).max())
    T_world_cam = homogeneous(R_WORLD_CAM_DOWN, location)
    camera = params.camera()
    if cfg.camera_tilt_deg > 0:
        T_world_cam = tilted(T_world_cam, cfg.camera_tilt_deg, cfg.camera_azimuth_deg)
        if near is None or far is None:  # a derived plane: derived again for the tilted camera
            clips = [tilted_clip(camera, T_world_cam, b, D, cfg) for b in bins]
            params = dataclasses.replace(params, clip_start=float(near or min(c[0] for c in clips)),
                                         clip_end=float(far or max(c[1] for c in clips)))
            camera = params.camera()
    rig = Rig(bin_geom, params, camera, T_world_cam, radius, bins)
    check_camera_range(rig, cfg)
    check_bin_area(rig, cfg)
    return rig


def scaled_camera_file(cfg: SceneConfig) -> Camera:
    """The camera of ``cfg.camera_file`` at ``cfg.camera_scale`` x its pixels; an image the camera
    checks refuse (no pixel left, too many) is an error naming the file and the scale."""
    given = read_camera_file(cfg.camera_file)
    if cfg.camera_scale == 1:
        return given
    source = f"{cfg.camera_file} at scene.camera_scale={cfg.camera_scale:g}"
    try:
        return given.scaled(cfg.camera_scale).check_plausible(source)
    except ValueError as e:
        raise ValueError(str(e) if str(e).startswith(source) else f"{source}: {e}") from None


def totes(obj: ObjectModel, drops: int, cfg: SceneConfig) -> tuple[BinGeometry, ...]:
    """The tote of each bin model of ``cfg`` sized to ``obj`` (one without ``bin_models``)."""
    cfg = cfg.for_part(obj.diameter)
    return tuple(bin_geometry(obj, drops, model) for model in cfg.bin_model_scenes())


def bin_geometry(obj: ObjectModel, drops: int, cfg: SceneConfig) -> BinGeometry:
    """The tote of ``cfg``'s bin keys for ``drops`` parts of ``obj`` (sizes: see the module docstring)."""
    extent = np.sort(obj.extent)
    D = obj.diameter
    inner = cfg.bin_inner or max(2.0 * D, math.sqrt(drops * extent[1] * extent[2] / cfg.bin_layers))
    wall = cfg.bin_wall_height or cfg.bin_wall_factor * D
    if cfg.bin_max_fill is not None:  # the hulls' volume over the fill: what the walls must hold
        held = drops * hull_volume(obj) / cfg.bin_max_fill
        if cfg.bin_inner is None:  # the automatic floor widens: the pile stays as high as the walls allow
            inner = max(inner, held / wall / cfg.bin_inner_y if cfg.bin_inner_y else math.sqrt(held / wall))
        elif cfg.bin_wall_height is None:  # a floor given: the automatic walls rise
            wall = max(wall, held / (inner * (cfg.bin_inner_y or inner)))
    return BinGeometry(inner, wall, cfg.bin_wall_thickness, cfg.bin_inner_y, cfg.bin_hole_size, cfg.bin_hole_pitch)


def hull_volume(obj: ObjectModel) -> float:
    """Volume of the part's convex hull, cubic metres (defined for a mesh that is not watertight)."""
    return float(obj.mesh.convex_hull.volume)


def bin_fill(obj: ObjectModel, drops: int, bin_geom: BinGeometry) -> float:
    """How full ``drops`` parts make the bin: their convex hulls over the volume inside the walls
    (floor area x wall height). Piles top out at about twice this in wall heights."""
    return drops * hull_volume(obj) / (float(np.prod(bin_geom.sides)) * bin_geom.wall_height)


def check_camera_range(rig: Rig, cfg: SceneConfig) -> None:
    """Refuse a rig whose far clip plane lies beyond a depth camera's range (:data:`MAX_CLIP_END_M`):
    the automatic camera raised to see a working area or a bin tens of metres across. Checked before
    anything is written (the written parameter.json would be refused, naming itself, not the key).

    Raises:
        ValueError: naming the settings that place the camera so far.
    """
    if rig.camera.clip_end <= MAX_CLIP_END_M:
        return
    keys = [f"{k}={list(v) if isinstance(v, tuple) else v}" for k in ("bin_area", "bin_inner", "bin_inner_y", "camera_height",
                                                                      "camera_tilt_deg") if (v := getattr(cfg, k))]
    raise ValueError(f"scene config: {', '.join(keys) or 'the bin'}: the camera {rig.params.location[2]:.3g} m above the floor "
                     f"would need a far clip plane {rig.camera.clip_end:.3g} m away, beyond a depth camera's "
                     f"{MAX_CLIP_END_M:g} m; give a smaller working area or bin")  # fmt: skip


def _check_jitter(cfg: SceneConfig, height: float, wall: float, half_fov_deg: float) -> None:
    """Refuse a camera no bin can be seen from (below the wall tops), and jitters no camera can take:
    reaching down to the wall tops, or tilting the bin centre out of the image. Each names the key given."""
    if cfg.camera_height is not None and height <= wall:
        raise ValueError(f"scene config: camera_height={cfg.camera_height:g} m puts the camera below the top of the bin "
                         f"walls ({wall:.3f} m above the floor); expected more than {wall + cfg.camera_jitter_m:.3f} "
                         "(the walls and camera_jitter_m)")  # fmt: skip
    if cfg.camera_jitter_m >= height - wall:
        raise ValueError(f"scene config: camera_jitter_m={cfg.camera_jitter_m} m would move the camera down to the bin "
                         f"walls (camera {height:.3f} m above the floor, walls {wall:.3f} m); expected < {height - wall:.3f}")
    if cfg.camera_jitter_deg >= half_fov_deg:
        fov = "the camera of scene.camera_file" if cfg.camera_file else f"scene.fov_deg={cfg.fov_deg:g}"
        raise ValueError(f"scene config: camera_jitter_deg={cfg.camera_jitter_deg} would tilt the bin centre out of the "
                         f"image: half the field of view is {half_fov_deg:.1f} degrees ({fov}); expected "
                         f"camera_jitter_deg < {half_fov_deg:.1f}, or a wider field of view")


def sample_layout(rig: Rig, cfg: SceneConfig, rng: np.random.Generator) -> CycleLayout:
    """Place the bin (x, y in ``bin_area`` or the jitter, yaw, tilt) and jitter the camera
    (position, small tilt) for one cycle. The draws of the defaults are those of every earlier
    dataset (a level bin near the origin): their bytes do not change."""
    u = rng.uniform(-1.0, 1.0, 2)
    if cfg.bin_area is None:
        dx, dy = u * cfg.bin_jitter_m
    else:
        x0, y0, x1, y1 = cfg.bin_area
        dx, dy = x0 + (x1 - x0) * (u[0] + 1.0) / 2.0, y0 + (y1 - y0) * (u[1] + 1.0) / 2.0
    w = rng.uniform(-1.0, 1.0)
    if cfg.bin_yaw_deg is None:
        yaw = math.radians(cfg.bin_jitter_deg) * w
    else:
        lo, hi = cfg.bin_yaw_deg
        yaw = math.radians(lo + (hi - lo) * (w + 1.0) / 2.0)
    T_world_ground = homogeneous(rotation_about(np.array([0.0, 0.0, 1.0]), yaw), np.array([dx, dy, 0.0]))
    axis = rng.standard_normal(3)
    angle = math.radians(cfg.camera_jitter_deg) * rng.uniform(0.0, 1.0)
    shift = rng.uniform(-1.0, 1.0, 3) * cfg.camera_jitter_m
    T_jitter = homogeneous(rotation_about(axis, angle), shift)
    if cfg.bin_tilt_deg <= 0:
        return CycleLayout(T_world_ground, T_jitter @ rig.T_world_cam)
    # drawn after the camera's: a tilted bin's dataset sees the cameras of the level one
    direction, tilt = rng.uniform(0.0, 2.0 * math.pi), math.radians(cfg.bin_tilt_deg) * rng.uniform(0.0, 1.0)
    T_tilt = homogeneous(rotation_about(np.array([math.cos(direction), math.sin(direction), 0.0]), tilt), np.zeros(3))
    T_tilt[2, 3] = bin_lift(rig.bin, T_tilt[:3, :3])
    return CycleLayout(T_world_ground @ T_tilt, T_jitter @ rig.T_world_cam, T_world_ground=T_world_ground)


def bin_lift(bin_geom: BinGeometry, R_tilt: np.ndarray) -> float:
    """How far a bin turned by ``R_tilt`` about its floor's centre must rise (metres) so that no
    corner of its underside goes below where the level underside was (the ground)."""
    hx, hy = (side / 2.0 + bin_geom.thickness for side in bin_geom.sides)
    t = bin_geom.thickness
    under = np.array([[x, y, -t] for x in (-hx, hx) for y in (-hy, hy)])
    return float(max(0.0, -t - float((under @ R_tilt.T)[:, 2].min())))


#: the bin model keys that move or resize a bin's floor
FLOOR_KEYS = ("bin_inner", "bin_inner_y", "bin_wall_thickness", "bin_clearance")


def check_bin_area(rig: Rig, cfg: SceneConfig) -> None:
    """Refuse a working area (``scene.bin_area``) whose corners the nominal camera does not see:
    a bin standing there would leave the image.

    Raises:
        ValueError: naming ``scene.bin_area``, the corner and where it falls.
    """
    if cfg.bin_area is None:
        return
    x0, y0, x1, y1 = cfg.bin_area
    corners = ((x0, y0), (x1, y0), (x0, y1), (x1, y1))
    for x, y in corners:
        if (where := _outside_view(rig, np.array([x, y, 0.0]))) is not None:
            raise ValueError(f"scene config: bin_area={list(cfg.bin_area)}: its corner ({x:g}, {y:g}) m lies outside "
                             f"the camera's view ({where}); give an area of the floor the camera sees")
    if cfg.bin_models is None:
        return
    for i, (b, model) in enumerate(zip(rig.bins, cfg.bin_models, strict=True)):
        # every bin model's floor that is not the configured bin's, in any yaw, wherever the area lets it stand (a
        # model that changes only the perforation or the wall height stands where the configured bin does)
        if not any(key in FLOOR_KEYS for key, _ in model):
            continue
        r = math.hypot(*(side / 2.0 for side in b.sides))
        for (x, y), a in itertools.product(corners, np.radians(np.arange(0.0, 360.0, 15.0))):
            if (where := _outside_view(rig, np.array([x + r * math.cos(a), y + r * math.sin(a), 0.0]))) is not None:
                raise ValueError(f"scene config: bin_models[{i}]: its floor ({b.sides[0]:g} x {b.sides[1]:g} m) standing "
                                 f"at the bin_area corner ({x:g}, {y:g}) m leaves the camera's view ({where}); give a "
                                 "smaller bin or working area, or a higher camera")


def _outside_view(rig: Rig, point_world: np.ndarray) -> str | None:
    """None where the nominal camera sees ``point_world``, else where it falls instead."""
    T_cam_world, cam = inverse_pose(rig.T_world_cam), rig.camera
    p = T_cam_world[:3, :3] @ point_world + T_cam_world[:3, 3]
    u = cam.fx * p[0] / p[2] + cam.cx if p[2] > 0 else math.nan
    v = cam.fy * p[1] / p[2] + cam.cy if p[2] > 0 else math.nan
    if -0.5 <= u <= cam.width - 0.5 and -0.5 <= v <= cam.height - 0.5:
        return None
    where = f"at pixel ({u:.0f}, {v:.0f})" if p[2] > 0 else "behind the camera"
    return f"{where} of the {cam.width} x {cam.height} image"


def view_layout(rig: Rig, cfg: SceneConfig, pile: CycleLayout, rng: np.random.Generator) -> CycleLayout:
    """Another view of a settled pile: the camera placed relative to the pile's bin as in a fresh,
    independent cycle (bin jitter and camera jitter drawn anew, then the camera carried along with
    the bin onto the pile's bin pose). Each view's bin-to-camera pose thus has exactly the
    distribution of a cycle's; only the pile is shared (``scene.views``)."""
    fresh = sample_layout(rig, cfg, rng)
    T_bin_cam = inverse_pose(fresh.T_world_bin) @ fresh.T_world_cam
    # the ground as the fresh cycle has it under its bin, carried along the same way
    T_ground = None if fresh.T_world_ground is None else pile.T_world_bin @ fresh.T_bin_ground
    return CycleLayout(pile.T_world_bin, pile.T_world_bin @ T_bin_cam, pile.clutter, T_ground)

