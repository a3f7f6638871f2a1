"""One drop cycle in memory: physics, then rendering, then scene records (no disk access).

Random numbers: cycle c of a dataset with seed s draws everything from
``SeedSequence([s, c])``, split into one stream for the per-cycle jitter and one for the drops, so
a cycle is the same whichever worker makes it and whatever was made before. With ``scene.views``
= K, one simulated pile p gives the cycles pK .. pK + K - 1 (one camera each, :meth:`generate_views`).
With ``scene.bin_models``, pile p's bin model is drawn from a stream of its own
(:func:`bin_model_rng`); each model's bin is built once per worker (physics and rendering).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from typing import Self

import numpy as np

from opnet.datasets.record import SceneRecord
from opnet.objects.model import ObjectModel
from opnet.synthesis.clutter import clutter_mesh, sample_clutter
from opnet.synthesis.collision import CollisionModel, build_collision_model
from opnet.synthesis.config import SceneConfig
from opnet.synthesis.layout import CycleLayout, Rig, make_rig, sample_layout, view_layout
from opnet.synthesis.physics import BinSimulator, CycleStates, CycleStats, make_simulator
from opnet.synthesis.rendering import SceneRenderer
from opnet.synthesis.sensor import SensorModel, sensor_rng
from opnet.synthesis.spin import (
    check_flippable,
    check_spinnable,
    flip_rng,
    flip_turns,
    resolve_view_spin,
    spin_rng,
    spin_turns,
    spun,
)

#: the ground plate is this many bin widths wide (it fills the view around the bin)
GROUND_SCALE = 10.0


def cycle_rngs(seed: int, cycle: int) -> tuple[np.random.Generator, np.random.Generator]:
    """(layout generator, drop generator) of a cycle, from ``SeedSequence([seed, cycle])``."""
    layout_seq, drop_seq = np.random.SeedSequence([int(seed), int(cycle)]).spawn(2)
    return np.random.default_rng(layout_seq), np.random.default_rng(drop_seq)


def clutter_rng(seed: int, cycle: int) -> np.random.Generator:
    """The foreign pieces' generator of a cycle: the third child of ``SeedSequence([seed, cycle])``
    (the first two, :func:`cycle_rngs`, are unchanged by it)."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(cycle)]).spawn(3)[2])


def bin_model_rng(seed: int, pile: int) -> np.random.Generator:
    """The bin model's generator of a pile (``scene.bin_models``): the fourth child of
    ``SeedSequence([seed, pile])`` (the others, :func:`cycle_rngs` and :func:`clutter_rng`, are
    unchanged by it)."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(pile)]).spawn(4)[3])


def draw_bin_model(scene: SceneConfig, seed: int, pile: int) -> int:
    """Index of pile ``pile``'s bin model in ``scene.bin_models`` (probability weight / total); 0
    without models (nothing drawn)."""
    if scene.bin_models is None:
        return 0
    weights = np.asarray(scene.bin_model_weights, dtype=np.float64)
    return int(bin_model_rng(seed, pile).choice(len(weights), p=weights / weights.sum()))


def bin_model_record(scene: SceneConfig, rig: Rig, pile: int, model: int) -> dict:
    """What a pile's ``bin_model.json`` holds: the pile, the model's index and settings (as given in
    ``scene.bin_models``) and the bin they made (metres)."""
    b, used = rig.bins[model], scene.bin_model_scenes()[model]
    bin_ = {"inner": b.sides[0], "inner_y": b.sides[1], "wall_height": b.wall_height, "wall_thickness": b.thickness,
            "hole_size": b.hole_size, "hole_pitch": b.hole_pitch, "clearance": used.bin_clearance}
    return {"pile": int(pile), "bin_model": int(model), "settings": dict(scene.bin_models[model]), "bin": bin_}


def view_rng(seed: int, pile: int, view: int) -> np.random.Generator:
    """Camera generator of view ``view`` > 0 of pile ``pile`` (``scene.views``)."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(pile), int(view)]))


def scene_name(cycle: int, n: int) -> str:
    """Record name of scene ``n`` of ``cycle`` (the IPA reader's naming)."""
    return f"cycle_{cycle:04d}_{n:03d}"


@dataclass
class CycleResult:
    """A generated cycle.

    Attributes:
        cycle: the cycle number.
        records: ``records[n]`` is the scene with n objects, n = 0 .. drops (internal camera frame).
        R_cam_bin: (3, 3) float64 bin-to-camera rotation.
        t_cam_bin: (3,) float64 bin origin (floor top centre) in the camera frame, metres.
        layout: the cycle's jittered bin and camera poses in the world.
        stats: physics bookkeeping.
        solo_renders: solo render passes over the whole cycle (visibility denominators).
        bin_model: with ``scene.bin_models``, the pile's model (:func:`bin_model_record`); else None.
    """

    cycle: int
    records: list[SceneRecord]
    R_cam_bin: np.ndarray
    t_cam_bin: np.ndarray
    layout: CycleLayout
    stats: CycleStats
    solo_renders: int
    bin_model: dict | None = None


class CycleGenerator:
    """Makes whole cycles of one part in memory: one physics simulator and one EGL renderer.

    Args:
        obj: the part (needs a mesh).
        drops: parts dropped per cycle (scenes 0 .. drops).
        scene: camera, bin and physics settings; default :class:`SceneConfig()`.
        cycles: number of cycles of the dataset (only recorded in ``rig.params``).
        collision: a prepared collision model (default: built here, V-HACD cached on disk).
        sensor: the depth sensor applied, as given, to every rendered depth image (default ideal:
            exact); :func:`opnet.synthesis.generate.generate` passes it scaled by ``scene.camera_scale``.
    """

    def __init__(
        self,
        obj: ObjectModel,
        drops: int,
        scene: SceneConfig | None = None,
        cycles: int = 1,
        collision: CollisionModel | None = None,
        sensor: SensorModel | None = None,
    ) -> None:
        if drops < 0:
            raise ValueError(f"drops must be >= 0, got {drops}")
        self.obj, self.drops = obj, int(drops)
        # the settings sized to the part: the rig by D / rig_d, a small part's lengths (SceneConfig.for_part)
        self.scene = resolve_view_spin((scene or SceneConfig()).for_part(obj.diameter), obj)
        self.sensor = sensor or SensorModel()
        self.rig: Rig = make_rig(obj, self.drops, cycles, self.scene)
        assert obj.mesh is not None  # make_rig refuses mesh-less objects
        if self.scene.view_spin:  # before the collision model: a refusal costs no decomposition
            check_spinnable(obj.mesh, obj.diameter, self.scene.view_spin_tolerance, obj.name)
        self._flip_centre = (check_flippable(obj.mesh, obj.diameter, self.scene.view_spin_tolerance, obj.name)
                             if self.scene.view_flip else 0.0)
        self.collision = collision or build_collision_model(obj.mesh, self.scene)
        self._model_scenes = self.scene.bin_model_scenes()
        #: per bin model (0 without models): its rig, scene and simulator, made on first use
        self._bins: dict[int, tuple[Rig, SceneConfig, BinSimulator]] = {}
        self.simulator = self._bin(0)[2]
        self.renderer = SceneRenderer(
            obj.mesh,
            self.rig.camera,
            self.rig.bin.mesh(),
            ground_size=GROUND_SCALE * self.rig.bin.outer,
            ground_depth=self.rig.bin.thickness + self._model_scenes[0].bin_clearance,
            solo_cache_mm=self.scene.solo_cache_mm,
            solo_cache_deg=self.scene.solo_cache_deg,
        )

    def _bin(self, model: int) -> tuple[Rig, SceneConfig, BinSimulator]:
        """Bin model ``model``'s rig, scene and simulator, its bin added to the renderer (once)."""
        if model not in self._bins:
            rig, scene = self.rig.with_bin(model), self._model_scenes[model]
            if model:  # the renderer is made with model 0's bin
                self.renderer.add_bin(model, rig.bin.mesh(), GROUND_SCALE * rig.bin.outer,
                                      rig.bin.thickness + scene.bin_clearance)
            self._bins[model] = (rig, scene, make_simulator(rig, self.collision, scene))
        return self._bins[model]

    def close(self) -> None:
        for _, _, simulator in self._bins.values():
            simulator.close()
        self.renderer.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def generate(self, seed: int, cycle: int) -> CycleResult:
        """Simulate and render cycle ``cycle`` of the dataset with seed ``seed`` (with
        ``scene.views`` > 1: view ``cycle % views`` of pile ``cycle // views``)."""
        views = self.scene.views
        return next(self.generate_views(seed, cycle // views, (cycle % views,)))

    def generate_views(self, seed: int, pile: int, views: Iterable[int] | None = None) -> Iterator[CycleResult]:
        """Simulate pile ``pile`` once and render it from each of ``views`` (default all
        ``scene.views``); view k is written as cycle ``pile * scene.views + k``.

        Random numbers: the pile (bin jitter, drops) and view 0 come from ``cycle_rngs(seed,
        pile)`` exactly as a cycle without views (``views=1`` gives the same bytes as before);
        view k > 0 draws its camera from ``SeedSequence([seed, pile, k])`` (:func:`view_layout`) and, with
        ``scene.view_spin``, each part's spin about its own axis from a stream of its own (:func:`spin_rng`), with
        ``scene.view_flip`` each part's flip end over end (before its spin) from another (:func:`flip_rng`).
        Views are rendered one after another, each with its own visibility cache.
        """
        K = self.scene.views
        wanted = sorted(set(range(K) if views is None else views))
        if not wanted or wanted[0] < 0 or wanted[-1] >= K:
            raise ValueError(f"views {wanted} outside 0..{K - 1} (scene.views={K})")
        layout_rng, drop_rng = cycle_rngs(seed, pile)
        model = draw_bin_model(self.scene, seed, pile)
        rig, scene, simulator = self._bin(model)
        record = None if self.scene.bin_models is None else bin_model_record(self.scene, self.rig, pile, model)
        layout = sample_layout(rig, scene, layout_rng)
        if scene.clutter:
            pieces = sample_clutter(scene.clutter, rig.bin.sides, rig.object_radius, clutter_rng(seed, pile))
            layout = dataclasses.replace(layout, clutter=pieces)
        states = simulator.simulate(layout, self.drops, drop_rng)
        for k in wanted:
            view = layout if k == 0 else view_layout(rig, scene, layout, view_rng(seed, pile, k))
            shown = states
            if k and (self.scene.view_spin or self.scene.view_flip):  # new spins, flips (opnet.synthesis.spin)
                turns = (spin_turns(spin_rng(seed, pile, k), self.drops) if self.scene.view_spin
                         else np.tile(np.eye(4), (self.drops, 1, 1)))
                if self.scene.view_flip:
                    turns = turns @ flip_turns(flip_rng(seed, pile, k), self.drops, self._flip_centre)
                shown = spun(states, turns)
            self.renderer.select_bin(model)
            yield dataclasses.replace(self._render_view(seed, pile * K + k, view, shown), bin_model=record)

    def _outside_clip(self, depth: np.ndarray) -> np.ndarray:
        """``scene.outside_clip``: surfaces outside the clip planes at the plane they cross ("clamp")
        or left for the depth code to write as missing ("missing")."""
        if self.scene.outside_clip != "clamp":
            return depth
        # the planes as the depth's own floats, rounded inwards (the depth code keeps what lies on them)
        start, end = self.rig.camera.clip_start, self.rig.camera.clip_end
        lo, hi = (np.asarray(v, dtype=depth.dtype) for v in (start, end))
        lo = lo if float(lo) >= start else np.nextafter(lo, hi)  # float(): compared in float64, not float32
        hi = hi if float(hi) <= end else np.nextafter(hi, lo)
        return np.clip(depth, lo, hi)  # NaN (no depth) stays NaN

    def _render_view(self, seed: int, cycle: int, layout: CycleLayout, states: CycleStates) -> CycleResult:
        T_cam_world = layout.T_cam_world
        T_cam_bin = T_cam_world @ layout.T_world_bin
        self.renderer.begin_cycle(T_cam_bin, clutter_mesh(layout.clutter), T_cam_bin @ layout.T_bin_ground)
        records, solo_renders = [], 0
        for n, T_world_obj in enumerate(states.T_world_obj):
            T_cam_obj = T_cam_world @ T_world_obj  # (n, 4, 4)
            out = self.renderer.render(T_cam_obj)
            solo_renders += out.solo_renders
            records.append(
                SceneRecord(
                    name=scene_name(cycle, n),
                    depth=self._outside_clip(self.sensor.apply(out.depth, self.rig.camera, sensor_rng(seed, cycle, n))),
                    camera=self.rig.camera,
                    segmentation=out.segmentation,
                    R_cam_obj=T_cam_obj[:, :3, :3].copy(),
                    t_cam_obj=T_cam_obj[:, :3, 3].copy(),
                    visibility=out.visibility,
                    instance_id=np.arange(1, n + 1, dtype=np.int64),
                    object_name=self.obj.name,
                )
            )
        return CycleResult(cycle, records, T_cam_bin[:3, :3].copy(), T_cam_bin[:3, 3].copy(), layout,
                           states.stats, solo_renders)
