"""Settings of the synthetic bin-picking scenes: camera, bin, physics (docs/data.md#synthetic-data, paper §IV).

One flat dataclass so that every value is a Hydra override away (``scene.fov_deg=40``); ``None``
means "derive it from the object and the number of drops" (see :mod:`opnet.synthesis.layout`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

from opnet.geometry.camera import MAX_IMAGE_SIDE
from opnet.synthesis.fields import SETTING_GROUPS, _number, _numbers, _setting, from_known_keys  # noqa: F401 (SETTING_GROUPS: re-exported)
from opnet.synthesis.working_volume import CAMERA, camera_planes, from_recorded, metres, parse_clip, to_recorded

COLLISION_MODES = ("auto", "convex_hull", "vhacd")
#: the smallest perforation of a generated bin (metres) and the largest length of a scene setting (metres)
MIN_HOLE_M = 0.0005
MAX_SCENE_M = 20.0
#: the longest physics step, seconds (a longer one lets parts fall through the bin: no pile, only re-drops)
MAX_TIME_STEP = 0.05
#: physics engines of the generator (opnet.synthesis.physics)
PHYSICS_ENGINES = ("mujoco", "pybullet")
#: what the written depth holds where a surface lies outside the clip planes (``outside_clip``)
OUTSIDE_CLIP = ("missing", "clamp")
#: datasets made before ``physics`` existed were made with pybullet: the key is left out of
#: to_dict for that engine, so their generation.json still matches ``physics=pybullet``
_LEGACY_PHYSICS = "pybullet"
@dataclass(frozen=True)
class SceneConfig:
    """Camera, bin and physics settings of a generated dataset.

    Camera (the written ``parameter.json``; IPA convention: a crop of a square canvas):
        resolution: side of the square canvas, pixels (``resolution_big``).
        width, height: size of the written image, a centred crop of the canvas; None = resolution.
            ``resolution - width`` and ``resolution - height`` must be even.
        fov_deg: field of view of the canvas, degrees (``perspectiveAngle``).
        camera_height: distance from the camera to the bin floor, metres; None = the smallest
            height at which the whole bin rim fits into the image with ``view_margin`` to spare.
        view_margin: relative margin around the bin rim when ``camera_height`` is automatic;
            negative values cut the rim off (parts at the walls partly out of view).
        clip: the working volume, the one setting of the clip planes (the depth code spans them):
            null (derived from the camera height, the bin and the object diameter), ``camera`` (the
            camera file's) or ``[near, far]`` metres (:mod:`opnet.synthesis.working_volume`);
            ``clip_start`` / ``clip_end`` give its metres.
        camera_tilt_deg: the camera's optical axis this many degrees off vertical (0 = straight
            down, the default; real cells often look 15-30 degrees off), turned about the bin
            floor's centre so that the camera keeps looking at it from ``camera_height``.
        camera_azimuth_deg: the direction (about the vertical, from the world x axis) the camera
            is tilted towards.
        camera_jitter_m, camera_jitter_deg: per-cycle uniform jitter of the camera position (each
            axis, metres) and orientation (random axis, angle up to this many degrees).
        bin_jitter_m, bin_jitter_deg: per-cycle uniform jitter of the bin position on the ground
            (x and y, metres) and of its yaw (degrees).

    Where the bin stands (a real cell's bins are swapped, pushed and turned; the camera stays):
        bin_area: ``[x0, y0, x1, y1]`` metres, a rectangle of the ground in the world frame (its
            origin is the point of the floor the image centre looks at, x and y as the camera's
            azimuth measures them): each pile's bin floor centre is drawn uniformly in it,
            independently of the camera; None = within ``bin_jitter_m`` of the origin (then
            ``bin_jitter_m`` is not used). Every corner must be in the camera's view.
        bin_yaw_deg: ``[lo, hi]`` degrees, the range each pile's bin yaw is drawn from uniformly;
            None = ``[-bin_jitter_deg, bin_jitter_deg]``.
        bin_tilt_deg: each pile's bin tilted by up to this many degrees about a horizontal axis
            of any direction (a bin on an uneven floor or a pallet), lifted so that it stays above
            the ground; 0 = level. The ground stays level.

    Bin (a tote of five boxes standing on a ground plane; floor top = bin frame origin, z up):
        bin_inner: inner side of the floor (along the bin's x), metres; None = from the object and
            ``drops``.
        bin_inner_y: inner side along the bin's y, metres; None = ``bin_inner`` (a square floor).
        bin_layers: the automatic floor holds ``drops`` parts lying flat in about this many layers.
        bin_wall_height: inner wall height, metres; None = ``bin_wall_factor`` x object diameter
            (raised by ``bin_max_fill`` where ``bin_inner`` is given).
        bin_wall_factor: see ``bin_wall_height``.
        bin_max_fill: None, or the largest share of the volume inside the walls that the ``drops``
            parts' convex hulls may fill (a compact part piles higher than a flat one; piles top
            out at about twice the fill in wall heights): the automatic floor widens until they
            do, or with ``bin_inner`` given, the automatic walls rise; None = no cap.
        bin_wall_thickness: metres, walls and floor.
        bin_hole_size, bin_hole_pitch: a perforated sheet or wire basket: square holes of
            ``bin_hole_size`` metres every ``bin_hole_pitch`` metres through the floor and the
            walls, as the camera sees them (the physics keeps the solid bin); 0 = solid.
        bin_clearance: the bin stands on legs this many metres above the ground (what its holes
            show); 0 = on the ground.
        bin_models: None (one bin for every pile, the keys above) or a list of mappings, the bins a
            real cell swaps: each sets some of :data:`BIN_MODEL_KEYS` (the others as above) and
            optionally a ``weight`` (> 0, default 1); each pile's bin is one of them, drawn with
            probability weight / total from the pile's own random stream (the same for any worker
            count). The automatic camera and clip planes are sized for all of them.

    Foreign parts (:mod:`opnet.synthesis.clutter`):
        clutter: this many foreign pieces (discs and flat boxes sized after the part) lie on the
            floor of every pile before the parts fall: static, drawn like the bin (not parts),
            as the other kinds of parts in a real cell's bin; 0 = none. MuJoCo only.

    Depth outside the clip planes:
        outside_clip: "missing" (the default; as the datasets were always written) writes a
            surface nearer than ``clip_start`` or beyond ``clip_end`` as missing depth, which the
            network input then fills from its neighbours; "clamp" writes it at the plane it
            crosses, which is what the network sees of a real sensor's frame (its far ground and
            near clutter are measured, and the input clamps them to 0 or 1). Use "clamp" whenever
            the clip planes cut through the scene: a real rig's working volume
            (``clip: camera``) above a floor or a raised basket's ground.

    Physics:
        physics: the engine, "mujoco" (default) or "pybullet" (the datasets made before MuJoCo;
            the ``pybullet`` extra, CPython 3.11 only).
        collision: "convex_hull", "vhacd" (approximate convex decomposition, cached: CoACD for
            MuJoCo, pybullet's V-HACD for pybullet) or "auto" (a decomposition when the mesh volume
            is below ``convexity_threshold`` x its hull volume).
        convexity_threshold: see ``collision``.
        vhacd_resolution: voxel budget of pybullet's V-HACD.
        coacd_threshold: concavity threshold of CoACD (MuJoCo): smaller = more, finer hulls.
        max_convex_pieces: a decomposition of more convex pieces than this is merged toward this
            many, two pieces at a time into the joint hull that adds the least volume
            (:func:`~opnet.synthesis.collision.merge_convex_parts`): a physics step costs about the
            pieces in contact, so a part of 40 pieces piles slowly. 0: every piece.
        convex_merge_budget: the merging stops before the volume it adds exceeds this fraction
            of the pieces' volume (a part whose concave detail needs its pieces keeps them).
        cache_dir: folder of the decomposition cache; None = $OPNET_CACHE or ~/.cache/opnet.
        time_step: simulation step, seconds.
        solver_iterations: constraint solver iterations per step.
        friction, rolling_friction, restitution: contact parameters of every body.
        linear_damping, angular_damping: velocity damping of the parts, per second (a part left
            alone loses this fraction of its velocity per second).
        drop_gap: metres between the pile top and the lowest possible point of a spawned part.
        settle_linear, settle_angular: a pile is at rest when every part moves slower than these
            (m/s, rad/s) ...
        settle_checks: ... at this many consecutive checks, one check every ``check_every`` steps.
        check_every: see ``settle_checks``.
        settle_time_cap: simulated seconds after which a drop is recorded even if still moving.
        max_redrops: attempts per drop when parts leave the bin (the world is restored each time).
        max_cycle_restarts: whole-cycle restarts (fresh random stream) when a drop exhausts its attempts.

    Parts smaller than the lengths above are written for:
        small_part_d: the absolute lengths (``bin_wall_thickness``, ``drop_gap``, ``bin_jitter_m``,
            ``camera_jitter_m``) and ``settle_linear`` are set for parts of this diameter (metres)
            and more; a smaller part of diameter D gets each scaled by D / ``small_part_d``
            (:meth:`for_part`), so that a 15 mm pin falls from a gap, into walls, under jitters
            and to a rest of its own size. 0: never scaled. The built-in parts (51 mm and more) and
            every larger part are unaffected.
        sized_for_d: set by :meth:`for_part` (the D the settings were scaled for), None as configured.
        rig_d: the part diameter (metres) the camera rig is set up for: ``camera_height``, the clip
            planes (given, or the camera file's with ``clip: camera``) and the jitters
            (``camera_jitter_m``, ``bin_jitter_m``) are scaled by D / ``rig_d`` for a part of
            diameter D (:meth:`for_part`), so that every part is framed as the rig frames a part of
            ``rig_d``: the bin follows D already, and the whole scene scales with it (the image is the
            same at any size). None: the rig as given. A part of exactly ``rig_d`` keeps the
            settings as given, byte for byte. ``experiment=dense`` sets the Siléane bunny's D.

    Camera from a file (then ``resolution``, ``width``, ``height`` and ``fov_deg`` are not used):
        camera_file: a Siléane ``camera_params.txt``, an IPA ``parameter.json`` or a YAML with
            ``fx fy cx cy width height clip_start clip_end``: the intrinsics and image size of the
            generated images (non-square pixels and any principal point on the image).
        camera_scale: render at this many times the file's pixels (a number in (0, 4]; 1 = as
            the file says): the same field of view and pose, the sensor model's pixel-unit
            settings scaled with it (``SensorModel.scaled``), both as written to the dataset. 0.5
            makes the piles of a high-resolution camera 4x cheaper; a model trained on them runs
            on the camera's full frames (its input is a metric crop resized to the network's size).
        Domain randomization around the camera: ``camera_jitter_m`` (position, height included)
        and ``camera_jitter_deg`` (tilt) per cycle; the intrinsics stay those of the file at
        ``camera_scale`` (one camera per dataset; the training's zoom augmentation varies the
        apparent focal length).

    Several views per pile:
        views: each settled pile is rendered from this many cameras, each written as a cycle of
            its own (cycle ``pile * views + k``); every view's camera is placed relative to the
            bin as in an independent cycle (the jitters above), so one physics simulation yields
            ``views`` cycles of the same distribution. 1 = one camera per pile (as before).
        view_spin: every view after the first turns each part about its own model z-axis by a
            spin of its own (drawn per view, held through the drops): the views show new spins of
            the same settled pile (:mod:`opnet.synthesis.spin`). Only for a part whose convex hull
            is a body of revolution about z (a wheel, a rim, a flange), within
            ``view_spin_tolerance`` × D; refused otherwise. ``auto``: on exactly for such a part
            whose spins are not free (no revolution symmetry) with ``views`` > 1, off for any other
            (:func:`opnet.synthesis.spin.resolve_view_spin`; the dataset records what it was).
        view_flip: every view after the first turns each part with probability 1/2 end over end about a
            diameter through the middle of its hull (besides its spin, with ``view_spin``; drawn per view, held
            through the drops). Only for a part whose hull is symmetric about that mid-plane within
            ``view_spin_tolerance`` × D; refused otherwise (:mod:`opnet.synthesis.spin`).

    Rendering:
        solo_cache_mm, solo_cache_deg: an object's solo pixel count (the visibility denominator) is
            reused within a cycle while its pose moved less than this since it was counted.
    """

    resolution: int = _setting(512, "camera")
    width: int | None = _setting(None, "camera")
    height: int | None = _setting(None, "camera")
    fov_deg: float = _setting(50.0, "camera")
    camera_height: float | None = _setting(None, "cell", rig=True)
    view_margin: float = _setting(0.08, "camera")
    clip: Any = _setting(None, "cell", rig=True)
    camera_tilt_deg: float = _setting(0.0, "cell", later=True)
    camera_azimuth_deg: float = _setting(0.0, "cell", later=True)
    camera_jitter_m: float = _setting(0.005, "randomization", rig=True, part=True)
    camera_jitter_deg: float = _setting(1.0, "randomization")
    bin_jitter_m: float = _setting(0.01, "randomization", rig=True, part=True)
    bin_jitter_deg: float = _setting(5.0, "randomization")
    bin_inner: float | None = _setting(None, "cell", bin_model=True)
    bin_layers: float = _setting(1.5, "bin")
    bin_wall_height: float | None = _setting(None, "cell", bin_model=True)
    bin_wall_factor: float = _setting(0.6, "bin")
    bin_max_fill: float | None = _setting(None, "bin", later=True)
    bin_wall_thickness: float = _setting(0.01, "cell", part=True, bin_model=True)
    collision: str = _setting("auto", "physics")
    convexity_threshold: float = _setting(0.85, "physics")
    vhacd_resolution: int = _setting(1_000_000, "physics")
    cache_dir: str | None = _setting(None, "physics")
    time_step: float = _setting(1.0 / 120.0, "physics")
    solver_iterations: int = _setting(10, "physics")
    friction: float = _setting(0.5, "physics")
    rolling_friction: float = _setting(0.002, "physics")
    restitution: float = _setting(0.0, "physics")
    linear_damping: float = _setting(0.04, "physics")
    angular_damping: float = _setting(0.5, "physics")
    drop_gap: float = _setting(0.01, "physics", part=True)
    settle_linear: float = _setting(0.05, "physics", part=True)
    settle_angular: float = _setting(0.5, "physics")
    settle_checks: int = _setting(3, "physics")
    check_every: int = _setting(4, "physics")
    settle_time_cap: float = _setting(3.0, "physics")
    max_redrops: int = _setting(10, "physics")
    max_cycle_restarts: int = _setting(3, "physics")
    solo_cache_mm: float = _setting(0.3, "rendering")
    solo_cache_deg: float = _setting(0.3, "rendering")
    camera_file: str | None = _setting(None, "cell", later=True)
    views: int = _setting(1, "camera", later=True)
    physics: str = _setting("mujoco", "physics")
    coacd_threshold: float = _setting(0.1, "physics", later=True)
    max_convex_pieces: int = _setting(0, "physics", later=True)
    convex_merge_budget: float = _setting(0.01, "physics", later=True)
    bin_inner_y: float | None = _setting(None, "cell", later=True, bin_model=True)
    bin_hole_size: float = _setting(0.0, "cell", later=True, bin_model=True)
    bin_hole_pitch: float = _setting(0.0, "cell", later=True, bin_model=True)
    bin_clearance: float = _setting(0.0, "cell", later=True, bin_model=True)
    outside_clip: str = _setting("missing", "cell", later=True)
    clutter: int = _setting(0, "randomization", later=True)
    bin_area: tuple[float, float, float, float] | None = _setting(None, "cell", later=True)
    bin_yaw_deg: tuple[float, float] | None = _setting(None, "randomization", later=True)
    bin_tilt_deg: float = _setting(0.0, "randomization", later=True)
    bin_models: tuple | None = _setting(None, "bin", later=True)
    camera_scale: float = _setting(1.0, "camera", later=True)
    small_part_d: float = _setting(0.05, "sizing", later=True)
    sized_for_d: float | None = _setting(None, "sizing", later=True)
    rig_d: float | None = _setting(None, "sizing", later=True)
    view_spin: bool | str = _setting(False, "randomization", later=True)
    view_spin_tolerance: float = _setting(0.01, "randomization", later=True)
    view_flip: bool = _setting(False, "randomization", later=True)

    def __post_init__(self) -> None:
        def need(ok: bool, key: str, expected: str) -> None:
            if not ok:
                raise ValueError(f"scene config: {key}={getattr(self, key)!r}, expected {expected}")

        for field in dataclasses.fields(self):  # a number's type first: true is no 1 m, "abc" no TypeError below
            kind, value = field.type.removesuffix(" | None"), getattr(self, field.name)
            if kind not in ("int", "float") or (value is None and field.type.endswith("| None")):
                continue
            need(isinstance(value, int | float) and not isinstance(value, bool)
                 and (kind == "float" or float(value).is_integer()), field.name,
                 "a whole number" if kind == "int" else "a number")
            if kind == "int":
                object.__setattr__(self, field.name, int(value))  # 64.0 of a YAML file is the size 64
        need(8 <= self.resolution <= MAX_IMAGE_SIDE, "resolution", f"an integer in 8..{MAX_IMAGE_SIDE}")
        for key in ("width", "height"):
            value = getattr(self, key)
            need(value is None or (0 < value <= self.resolution and (self.resolution - value) % 2 == 0), key,
                 "None or a size <= resolution with (resolution - size) even (a centred crop)")
        need(0.0 < self.fov_deg < 170.0, "fov_deg", "degrees in (0, 170)")
        for key in ("camera_height", "bin_inner", "bin_wall_height", "bin_inner_y"):
            value = getattr(self, key)
            need(value is None or (math.isfinite(value) and value > 0), key, "None or a positive number of metres")
        object.__setattr__(self, "clip", parse_clip(self.clip, MAX_SCENE_M))
        need(CAMERA not in self.clip or self.camera_file is not None, "clip",
             "null or metres without scene.camera_file (camera: the file's planes)")
        need(self.collision in COLLISION_MODES, "collision", f"one of {COLLISION_MODES}")
        need(self.physics in PHYSICS_ENGINES, "physics", f"one of {PHYSICS_ENGINES} (the physics engine)")
        # a negative margin brings the camera closer than the rim: parts at the walls leave the view,
        # as on real cells where the camera sees only the middle of the bin
        need(math.isfinite(self.view_margin) and self.view_margin > -0.9, "view_margin", "a number > -0.9")
        for key in ("camera_jitter_m", "camera_jitter_deg", "bin_jitter_m", "bin_jitter_deg",
                    "friction", "rolling_friction", "restitution", "linear_damping", "angular_damping", "drop_gap", "solo_cache_mm", "solo_cache_deg",
                    "bin_hole_size", "bin_clearance"):
            need(math.isfinite(getattr(self, key)) and getattr(self, key) >= 0, key, "a number >= 0")
        for key in ("bin_layers", "bin_wall_factor", "bin_wall_thickness", "time_step", "settle_linear",
                    "settle_angular", "settle_time_cap", "convexity_threshold", "coacd_threshold"):
            need(math.isfinite(getattr(self, key)) and getattr(self, key) > 0, key, "a number > 0")
        need(self.time_step <= MAX_TIME_STEP, "time_step",
             f"seconds in (0, {MAX_TIME_STEP:g}] (the physics step; 1/120 by default)")
        for key in ("vhacd_resolution", "solver_iterations", "settle_checks", "check_every", "max_redrops"):
            need(int(getattr(self, key)) >= 1, key, "an integer >= 1")
        need(isinstance(self.max_convex_pieces, int) and not isinstance(self.max_convex_pieces, bool)
             and self.max_convex_pieces >= 0, "max_convex_pieces", "an integer >= 0 (0: no cap)")
        need(isinstance(self.convex_merge_budget, (int, float)) and not isinstance(self.convex_merge_budget, bool)
             and 0 <= self.convex_merge_budget <= 1, "convex_merge_budget",
             "a fraction in [0, 1] of the part's volume that merging pieces may add")
        need(self.bin_max_fill is None or (isinstance(self.bin_max_fill, (int, float))
                                            and not isinstance(self.bin_max_fill, bool) and 0 < self.bin_max_fill <= 1),
             "bin_max_fill", "null or a fraction in (0, 1] of the volume inside the walls")
        need(self.max_cycle_restarts >= 0, "max_cycle_restarts", "an integer >= 0")
        need(0 < self.camera_scale <= 4, "camera_scale", "a number in (0, 4] (x the pixels of scene.camera_file)")
        need(self.camera_scale == 1 or self.camera_file is not None, "camera_scale",
             "1 without scene.camera_file (it scales the pixels of the file's camera)")
        need(isinstance(self.views, int) and not isinstance(self.views, bool) and 1 <= self.views <= 1000, "views",
             "an integer in 1..1000 (views per settled pile)")
        need(isinstance(self.view_spin, bool) or self.view_spin == "auto", "view_spin",
             "true, false or auto (fresh spins per view; auto: where the part's hull lets them)")
        need(self.view_spin is not True or self.views > 1, "view_spin",
             "false with scene.views=1 (it turns the parts in the views after the first: set scene.views > 1)")
        need(isinstance(self.view_flip, bool), "view_flip", "true or false (fresh flips per view)")
        need(not self.view_flip or self.views > 1, "view_flip",
             "false with scene.views=1 (it turns the parts in the views after the first: set scene.views > 1)")
        need(0 < self.view_spin_tolerance < 1, "view_spin_tolerance",
             "a fraction of D in (0, 1): how far the turned hull may reach out of itself")
        need(self.camera_jitter_deg < 45.0, "camera_jitter_deg", "degrees in [0, 45) (the camera must still see the bin)")
        need(isinstance(self.camera_tilt_deg, (int, float)) and math.isfinite(self.camera_tilt_deg)
             and 0 <= self.camera_tilt_deg < 90, "camera_tilt_deg",
             "degrees in [0, 90) off vertical (90 looks along the floor)")
        need(self.bin_hole_size == 0 or (math.isfinite(self.bin_hole_pitch) and self.bin_hole_pitch > self.bin_hole_size),
             "bin_hole_pitch", f"metres > bin_hole_size={self.bin_hole_size} (holes with bars between them)")
        # bounds before anything is made: a micrometre pitch meant millions of bars (memory without end)
        need(self.bin_hole_size == 0 or self.bin_hole_size >= MIN_HOLE_M, "bin_hole_size",
             f"0 (solid) or at least {MIN_HOLE_M} m (a perforation a camera resolves)")
        need(self.bin_hole_size == 0 or self.bin_hole_pitch >= 2 * MIN_HOLE_M, "bin_hole_pitch",
             f"at least {2 * MIN_HOLE_M} m")
        for key in ("camera_height", "bin_inner", "bin_inner_y", "bin_wall_height",
                    "bin_clearance", "bin_wall_thickness"):  # fmt: skip
            value = getattr(self, key)
            need(value is None or value <= MAX_SCENE_M, key, f"at most {MAX_SCENE_M:g} metres (a bin-picking cell)")
        need(isinstance(self.clutter, int) and not isinstance(self.clutter, bool) and 0 <= self.clutter <= 200,
             "clutter", "an integer in 0..200 (foreign pieces per pile)")
        need(self.clutter == 0 or self.physics == "mujoco", "clutter",
             "0 with scene.physics=pybullet (foreign pieces are MuJoCo bodies)")
        need(self.outside_clip in OUTSIDE_CLIP, "outside_clip", f"one of {OUTSIDE_CLIP}")
        need(math.isfinite(self.small_part_d) and 0 <= self.small_part_d <= MAX_SCENE_M, "small_part_d",
             "metres >= 0 (the part size the lengths are set for; 0: never scaled)")
        need(self.rig_d is None or (math.isfinite(self.rig_d) and 0 < self.rig_d <= MAX_SCENE_M), "rig_d",
             "null or the positive diameter (metres) of the part the camera rig is set up for")
        need(isinstance(self.camera_azimuth_deg, (int, float)) and math.isfinite(self.camera_azimuth_deg),
             "camera_azimuth_deg", "a finite number of degrees")
        area = _numbers(self.bin_area, 4)
        need(self.bin_area is None or (area is not None and area[0] <= area[2] and area[1] <= area[3]
                                       and max(map(abs, area)) <= 100), "bin_area",
             "null or [x0, y0, x1, y1] metres of the ground with x0 <= x1 and y0 <= y1 (the bin centre's area)")
        yaw = _numbers(self.bin_yaw_deg, 2)
        need(self.bin_yaw_deg is None or yaw is not None, "bin_yaw_deg", "null or [lo, hi] degrees")
        need(yaw is None or yaw[0] <= yaw[1], "bin_yaw_deg", "[lo, hi] with lo <= hi (the yaw range is empty)")
        need(yaw is None or yaw[1] - yaw[0] <= 360, "bin_yaw_deg", "[lo, hi] spanning at most 360 degrees")
        need(_number(self.bin_tilt_deg) and 0 <= self.bin_tilt_deg <= 30, "bin_tilt_deg",
             "degrees in [0, 30] (the bin's tilt off level)")
        object.__setattr__(self, "bin_area", area)  # lists of a config or JSON file, as tuples of floats
        object.__setattr__(self, "bin_yaw_deg", yaw)
        if self.bin_models is not None:
            object.__setattr__(self, "bin_models", self._checked_bin_models())

    def _checked_bin_models(self) -> tuple[tuple[tuple[str, Any], ...], ...]:
        """``bin_models`` checked, each model as the top-level keys are (the same bounds, an error
        naming ``bin_models[i].<key>``), as sorted (key, value) pairs (hashable, one form per list)."""
        models = self.bin_models
        # a list of a YAML file or a JSON record, or a Hydra ListConfig of train.py's scene node
        if isinstance(models, (str, bytes, Mapping)) or not isinstance(models, Sequence) or not models:
            raise ValueError(f"scene config: bin_models={models!r}, expected null or a non-empty list of mappings "
                             f"of some of {list(BIN_MODEL_KEYS)} and weight")
        out = []
        for i, model in enumerate(models):
            model = dict(model) if isinstance(model, Mapping) else model
            if isinstance(model, tuple) and all(isinstance(kv, tuple) and len(kv) == 2 for kv in model):
                model = dict(model)  # the pairs of an already checked config
            name = f"bin_models[{i}]"
            if not isinstance(model, dict):
                raise ValueError(f"scene config: {name}={model!r}, expected a mapping of some of {list(BIN_MODEL_KEYS)}")  # noqa: TRY004
            unknown = sorted(set(model) - {*BIN_MODEL_KEYS, "weight"}, key=str)
            if unknown:
                raise ValueError(f"scene config: {name}: unknown keys {unknown}; expected some of "
                                 f"{[*BIN_MODEL_KEYS, 'weight']}")
            weight = model.get("weight", 1.0)
            if not (_number(weight) and weight > 0):
                raise ValueError(f"scene config: {name}.weight={weight!r}, expected a number > 0 (its share of the piles)")
            try:
                dataclasses.replace(self, bin_models=None, **{k: v for k, v in model.items() if k != "weight"})
            except ValueError as e:
                raise ValueError(str(e).replace("scene config: ", f"scene config: {name}.", 1)) from None
            out.append(tuple(sorted((k, float(v) if _number(v) else v) for k, v in model.items())))
        return tuple(out)

    #: the settings :meth:`for_part` scales for a part smaller than ``small_part_d`` (fields declared ``part``)
    PART_LENGTHS: ClassVar[tuple[str, ...]]
    #: the settings :meth:`for_part` scales by D / ``rig_d`` (fields declared ``rig``; besides the camera
    #: file's clip planes)
    RIG_LENGTHS: ClassVar[tuple[str, ...]]

    def for_part(self, diameter: float) -> SceneConfig:
        """The settings used for a part of ``diameter`` metres, once (settings already sized are
        returned as they are: the same scene whoever sizes it first):

        - with ``rig_d``: :data:`RIG_LENGTHS` (and the camera file's clip planes with
          ``clip: camera``, written as metres) scaled by
          ``diameter / rig_d``; ``rig_d`` is then spent (None in the result);
        - :data:`PART_LENGTHS` not scaled by the rig, by ``diameter / small_part_d`` where that is
          below 1.

        ``self`` where nothing changes (a part of exactly ``rig_d`` and at least ``small_part_d``)."""
        if self.sized_for_d is not None or not diameter > 0:
            return self
        changes: dict[str, Any] = {}
        rig = diameter / self.rig_d if self.rig_d else 1.0
        if self.rig_d is not None:
            changes["rig_d"] = None
        if rig != 1.0:
            values = {k: getattr(self, k) for k in self.RIG_LENGTHS}
            if CAMERA in self.clip:
                from opnet.datasets.camera_file import read_camera_file

                values["clip"] = camera_planes(self.clip, read_camera_file(self.camera_file))
            changes.update({k: v * rig for k, v in values.items() if v is not None and k != "clip"})
            if any(v is not None for v in values["clip"]):
                changes["clip"] = [None if v is None else v * rig for v in values["clip"]]
        if 0 < diameter < self.small_part_d:
            factor = diameter / self.small_part_d
            changes.update({k: getattr(self, k) * factor for k in self.PART_LENGTHS if k not in changes})
        if any(k != "rig_d" for k in changes):
            changes["sized_for_d"] = float(diameter)
        return dataclasses.replace(self, **changes) if changes else self

    def bin_model_scenes(self) -> list[SceneConfig]:
        """The scene of each bin model (its keys set, ``bin_models`` None); ``[self]`` without models."""
        if self.bin_models is None:
            return [self]
        return [dataclasses.replace(self, bin_models=None, **{k: v for k, v in m if k != "weight"})
                for m in self.bin_models]

    @property
    def bin_model_weights(self) -> tuple[float, ...]:
        """Each bin model's weight (1 where not given); ``(1.0,)`` without models."""
        return tuple(dict(m).get("weight", 1.0) for m in self.bin_models or ((),))

    @property
    def yaw_range_deg(self) -> tuple[float, float]:
        """(lo, hi) of the bin's yaw, degrees."""
        return self.bin_yaw_deg or (-self.bin_jitter_deg, self.bin_jitter_deg)

    @property
    def clip_start(self) -> float | None:
        """The near plane's metres where ``clip`` gives them (None: derived, or the camera file's)."""
        return metres(self.clip[0])

    @property
    def clip_end(self) -> float | None:
        """The far plane's metres where ``clip`` gives them."""
        return metres(self.clip[1])

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) of the written image, pixels."""
        return (self.width or self.resolution, self.height or self.resolution)

    @classmethod
    def from_dict(cls, values: Mapping[str, Any] | None) -> SceneConfig:
        """Build from a mapping (a Hydra ``scene`` node, a plain dict or a dataset's recorded ``scene``, whose
        ``clip_start`` / ``clip_end`` / ``camera_file_clip`` are read into ``clip``); unknown keys are errors."""
        return from_known_keys(cls, from_recorded(values or {}, "scene config"), "scene config")

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict (the inverse of :meth:`from_dict`); fields added after datasets
        existed are left out at their defaults, so those datasets' ``generation.json`` still match."""
        out: dict[str, Any] = {}
        for key, value in dataclasses.asdict(self).items():  # the working volume as every dataset records it
            out.update(to_recorded(self.clip) if key == "clip" else {key: value})
        for key in ("bin_area", "bin_yaw_deg"):
            out[key] = None if out[key] is None else list(out[key])
        out["bin_models"] = None if self.bin_models is None else [dict(m) for m in self.bin_models]
        for key in _LATER_FIELDS:
            if out[key] == getattr(SceneConfig, key):
                del out[key]
        if out["physics"] == _LEGACY_PHYSICS:
            del out["physics"]
        return out



def scene_keys(flag: str | None = None, group: str | None = None) -> tuple[str, ...]:
    """The :class:`SceneConfig` fields declared with ``flag`` (``later``, ``rig``, ``part``, ``bin_model``)
    and / or in ``group`` (:data:`SETTING_GROUPS`), in declaration order; every field without either."""
    return tuple(f.name for f in dataclasses.fields(SceneConfig)
                 if (flag is None or f.metadata[flag]) and (group is None or f.metadata["group"] == group))


#: fields added after the first datasets were made (left out of to_dict at their defaults)
_LATER_FIELDS = scene_keys("later")
#: the keys a bin model (``scene.bin_models``) may set, besides its ``weight``
BIN_MODEL_KEYS = scene_keys("bin_model")
SceneConfig.PART_LENGTHS = scene_keys("part")
SceneConfig.RIG_LENGTHS = scene_keys("rig")
