"""Generate a synthetic IPA-layout dataset: parallel, resumable, byte-deterministic.

Work is split by whole cycles. Each worker process (``spawn`` start method: physics engines and EGL do
not survive a fork) owns one :class:`CycleGenerator` (one physics simulator, one EGL context). Every
cycle draws its random numbers from ``SeedSequence([seed, cycle])`` and starts its physics world
from scratch, so the files do not depend on the number of workers or on the order of the cycles.
Files are written atomically and the scene CSVs last, so a killed run leaves complete cycles and
an incomplete one; re-running deletes and remakes the incomplete cycles and skips the rest, giving
the same bytes as an uninterrupted run.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tqdm import tqdm

from opnet._deps import require
from opnet._limits import check_threads
from opnet._pool import spawn_imap_unordered
from opnet._repr import short_repr
from opnet.objects.model import ObjectModel
from opnet.synthesis.collision import CollisionModel, build_collision_model, check_solid
from opnet.synthesis.config import SceneConfig
from opnet.synthesis.layout import make_rig
from opnet.synthesis.sensor import SensorModel
from opnet.synthesis.spin import resolve_view_spin
from opnet.synthesis.writer import (
    clear_cycle,
    cycle_complete,
    normalized_object_config,
    object_config_for,
    preview_cycles,
    write_cycle,
    write_root_files,
)

log = logging.getLogger(__name__)


@dataclass
class GenerationReport:
    """What :func:`generate_dataset` did.

    Attributes:
        out: the dataset folder.
        cycles: cycles the dataset has; cycles_generated: made by this call; cycles_skipped:
            already complete; piles_simulated: physics simulations run (one pile gives up to
            ``scene.views`` cycles).
        scenes_written: scenes written by this call (``cycles_generated * (drops + 1)``).
        seconds: wall time of the call; startup_seconds: until the first worker was ready
            (process start, imports, EGL and physics set-up).
        scenes_per_second: ``scenes_written`` / (``seconds`` - ``startup_seconds``).
        redrops, unsettled, restarts, physics_steps, solo_renders: totals over generated cycles.
        per_cycle_seconds: time each simulated pile took (simulate, render and write its views).
        worker_busy: per worker process id, (scenes written, seconds spent on them).
    """

    out: Path
    cycles: int
    cycles_generated: int = 0
    cycles_skipped: int = 0
    piles_simulated: int = 0
    scenes_written: int = 0
    seconds: float = 0.0
    startup_seconds: float = 0.0
    redrops: int = 0
    unsettled: int = 0
    restarts: int = 0
    physics_steps: int = 0
    solo_renders: int = 0
    per_cycle_seconds: list[float] = field(default_factory=list)
    worker_busy: dict[int, tuple[int, float]] = field(default_factory=dict)

    @property
    def scenes_per_second(self) -> float:
        busy = self.seconds - self.startup_seconds
        return self.scenes_written / busy if busy > 0 else 0.0

    @property
    def steady_scenes_per_second(self) -> float:
        """Sum over workers of scenes / seconds spent making them (no start-up, no idle tail)."""
        return sum(n / t for n, t in self.worker_busy.values() if t > 0)


@dataclass(frozen=True)
class _Job:
    """Everything a worker needs (pickled once per worker)."""

    obj: ObjectModel
    root: Path
    drops: int
    cycles: int
    seed: int
    scene: SceneConfig
    collision: CollisionModel
    previews: frozenset[int]
    sensor: SensorModel


@dataclass(frozen=True)
class _CycleDone:
    """One finished pile: the cycles (views) it wrote."""

    cycles: tuple[int, ...]
    seconds: float
    ready_at: float
    redrops: int
    unsettled: int
    restarts: int
    steps: int
    solo_renders: int
    worker: int


class _Worker:
    def __init__(self, job: _Job) -> None:
        from opnet.synthesis.cycle import CycleGenerator  # physics and rendering: only where piles are made

        self.job = job
        self.generator = CycleGenerator(job.obj, job.drops, job.scene, job.cycles, job.collision, job.sensor)
        self.ready_at = time.time()

    def run(self, pile: tuple[int, tuple[int, ...]]) -> _CycleDone:
        """Simulate pile ``pile[0]`` and write its views ``pile[1]`` (each a cycle)."""
        start = time.perf_counter()
        job, (index, views) = self.job, pile
        written, solo = [], 0
        for result in self.generator.generate_views(job.seed, index, views):
            write_cycle(job.root, result, (job.drops,) if result.cycle in job.previews else ())
            written.append(result.cycle)
            solo += result.solo_renders
        s = result.stats
        return _CycleDone(tuple(written), time.perf_counter() - start, self.ready_at, s.redrops, s.unsettled,
                          s.restarts, s.steps, solo, os.getpid())


_WORKER: _Worker | None = None


def _init_worker(job: _Job, threads: int) -> None:
    global _WORKER
    # llvmpipe (software GL) rasterizes with one thread per CPU in every worker: split the CPUs
    os.environ.setdefault("LP_NUM_THREADS", str(threads))
    # MuJoCo simulates here, it does not render (pyrender does): without this, importing it loads
    # glfw, which probes its library's version in a child process at every worker start
    os.environ.setdefault("MUJOCO_GL", "disable")
    _WORKER = _Worker(job)


def _run_pile(pile: tuple[int, tuple[int, ...]]) -> _CycleDone:
    assert _WORKER is not None, "worker not initialized"
    return _WORKER.run(pile)


def _metres(value: float | None) -> str:
    return "derived" if value is None else f"{value:.3f} m"


#: the most parts a pile (ids 1..254 of the 8-bit segmentation; 0 is the bin, 255 the background)
MAX_DROPS = 254


def generate_dataset(
    obj: ObjectModel,
    out: Path,
    cycles: int,
    drops: int,
    workers: int = 1,
    seed: int = 0,
    scene: SceneConfig | None = None,
    progress: bool = True,
    previews: int = 4,
    object_config: Mapping[str, Any] | None = None,
    sensor: SensorModel | Mapping[str, Any] | None = None,
) -> GenerationReport:
    """Generate (or complete) an IPA-layout dataset of ``cycles`` x (``drops`` + 1) scenes.

    Args:
        obj: the part (needs a mesh).
        out: dataset folder; created, or completed if it holds a dataset with the same settings.
        cycles: number of drop cycles (``cycle_0000`` ..).
        drops: parts per cycle; scenes 000 (empty bin) .. ``drops``. At most 254 (uint8 ids).
        workers: worker processes; 1 runs in this process.
        seed: dataset seed; cycle c uses ``SeedSequence([seed, c])``.
        scene: camera, bin and physics settings (default :class:`SceneConfig()`).
        progress: show a tqdm bar (scenes).
        previews: how many cycles (spread evenly) get ``preview/cycle_XXXX_NNN.png`` of their
            full scene.
        object_config: the object config to store in ``object.json`` (keys of conf/object/*.yaml);
            default: the built-in's name, or a copy of the mesh in ``out``.
        sensor: the depth sensor's artefacts (:mod:`opnet.synthesis.sensor`; a model or the
            ``sensor`` config node); default ideal (exact depth). Its pixel-unit settings refer to
            the camera's pixels: with ``scene.camera_scale`` they are scaled with the image, and the
            dataset records the scaled model (the one applied).
    Returns:
        What was done, with timings.
    Raises:
        ValueError: bad arguments, or ``out`` holds a dataset made with other settings.
    """
    # the seed: SeedSequence takes no negative one; the drops: ids of the 8-bit segmentation (0 bin, 255 background)
    for key, value, high in (("cycles", cycles, None), ("drops", drops, MAX_DROPS), ("seed", seed, None),
                             ("previews", previews, None)):  # fmt: skip
        if isinstance(value, bool) or not isinstance(value, int) or value < 0 or (high is not None and value > high):
            bound = ">= 0" if high is None else f"in 0..{high} (parts a pile, each an id of the 8-bit segmentation)"
            raise ValueError(f"{key}={short_repr(value)}: expected a whole number {bound}")
    check_threads(workers, "workers")
    start, wall_start = time.perf_counter(), time.time()
    out, scene = Path(out), scene or SceneConfig()
    if out.exists() and not out.is_dir():  # a file, /dev/null
        raise ValueError(f"out={out}: exists and is not a folder; choose another out=")
    sensor = (sensor if isinstance(sensor, SensorModel) else SensorModel.from_dict(sensor)).scaled(scene.camera_scale)
    # the settings sized to the part (SceneConfig.for_part: the rig scaled by D / rig_d, a small part's lengths
    # by D / small_part_d), as recorded in generation.json (a dataset made before that is then not completed)
    given, scene = scene, resolve_view_spin(scene.for_part(obj.diameter), obj)  # scene.view_spin=auto decided
    if given.view_spin == "auto" and scene.view_spin:
        log.info("scene.view_spin=auto: %s's convex hull is a body of revolution about its axis and its spins are not "
                 "free: every view after a pile's first turns its parts about their axes", obj.name)
    if given.rig_d and scene.sized_for_d is not None:
        log.info("the camera rig (scene.rig_d: set up for a part of D %.1f mm) scaled to this part's D %.1f mm: camera "
                 "height %s, clip planes %s-%s, jitters %.1f mm; scene.rig_d=null keeps the rig as given",
                 1e3 * given.rig_d, 1e3 * obj.diameter, _metres(scene.camera_height), _metres(scene.clip_start),
                 _metres(scene.clip_end), 1e3 * scene.camera_jitter_m)
    rig = make_rig(obj, drops, cycles, scene)
    config = normalized_object_config(object_config) if object_config is not None else object_config_for(obj, out)
    if obj.mesh is not None:
        try:
            check_solid(obj.mesh)  # before anything is written: a flat mesh cannot be dropped
        except ValueError as e:
            raise ValueError(f"{config.get('mesh') or obj.name}: {e}") from None
    params = rig.params
    present = _cycles_present(out)
    if present and present[-1] + 1 > cycles:
        # a re-run with fewer cycles leaves the dataset's other cycles in place: parameter.json
        # must keep counting them (number_cycles = cycle folders), not shrink below the folders
        params = dataclasses.replace(params, number_cycles=present[-1] + 1)
    todo = [c for c in range(cycles) if not cycle_complete(out, c, drops)]
    collision = None
    if todo:  # before anything is written: a dataset must not announce cycles that cannot be made here
        _require_generator(out, scene)
        assert obj.mesh is not None
        try:
            collision = build_collision_model(obj.mesh, scene)
        except ValueError as e:  # the convex decomposition failed
            raise ValueError(f"{config.get('mesh') or obj.name}: {e}") from None
    write_root_files(out, obj, config, params, scene, seed, drops, sensor, complete=not todo)
    for c in todo:
        clear_cycle(out, c)
    report = GenerationReport(out, cycles, cycles_skipped=cycles - len(todo))
    if collision is not None:
        job = _Job(obj, out, drops, cycles, seed, scene, collision,
                   frozenset(preview_cycles(cycles, previews)), sensor)
        piles = piles_to_make(todo, scene.views)
        with tqdm(total=len(todo) * (drops + 1), unit="scene", disable=not progress, desc=f"generating {out.name}") as bar:
            for done in _run(job, piles, min(workers, len(piles))):
                bar.update(len(done.cycles) * (drops + 1))
                _account(report, done, drops, done.ready_at - wall_start)
    report.seconds = time.perf_counter() - start
    report.startup_seconds = min(report.startup_seconds, report.seconds)
    return report


def _require_generator(out: Path, scene: SceneConfig) -> None:
    """Physics (the engine ``scene.physics`` names) and rendering are installed (only checked when
    cycles are to be made: a complete dataset is used without them)."""
    hint = (f"install it, or generate {out} on a machine that has it and copy it here: a complete dataset is "
            "used without the generator")
    extra = " (scene.physics=pybullet: CPython 3.11 wheels only; scene.physics=mujoco needs no pybullet)"
    require(scene.physics, f"generating cycles of {out}", hint + (extra if scene.physics == "pybullet" else ""))
    require("pyrender", f"generating cycles of {out}", hint)


def _cycles_present(root: Path) -> list[int]:
    """Indices of the ``gt/cycle_XXXX`` folders of a dataset folder, sorted."""
    gt = root / "gt"
    if not gt.is_dir():
        return []
    return sorted(int(p.name[6:]) for p in gt.iterdir() if p.is_dir() and p.name.startswith("cycle_") and p.name[6:].isdigit())


def piles_to_make(cycles: list[int], views: int) -> list[tuple[int, tuple[int, ...]]]:
    """The piles that ``cycles`` come from, each with the views (cycle % views) to write."""
    piles: dict[int, list[int]] = {}
    for c in cycles:
        piles.setdefault(c // views, []).append(c % views)
    return [(p, tuple(v)) for p, v in sorted(piles.items())]


def _run(job: _Job, piles: list[tuple[int, tuple[int, ...]]], workers: int) -> Iterator[_CycleDone]:
    """Yield finished piles, in this process (workers == 1) or from a spawn pool."""
    if workers == 1:
        worker = _Worker(job)
        try:
            for p in piles:
                yield worker.run(p)
        finally:
            worker.generator.close()
        return
    threads = max(1, (os.cpu_count() or 1) // workers)
    yield from spawn_imap_unordered(_run_pile, piles, workers, _init_worker, (job, threads))


def _account(report: GenerationReport, done: _CycleDone, drops: int, ready_after: float) -> None:
    first = report.cycles_generated == 0
    scenes = len(done.cycles) * (drops + 1)
    report.cycles_generated += len(done.cycles)
    report.piles_simulated += 1
    report.scenes_written += scenes
    report.redrops += done.redrops
    report.unsettled += done.unsettled
    report.restarts += done.restarts
    report.physics_steps += done.steps
    report.solo_renders += done.solo_renders
    report.per_cycle_seconds.append(done.seconds)
    busy_scenes, seconds = report.worker_busy.get(done.worker, (0, 0.0))
    report.worker_busy[done.worker] = (busy_scenes + scenes, seconds + done.seconds)
    report.startup_seconds = ready_after if first else min(report.startup_seconds, ready_after)
