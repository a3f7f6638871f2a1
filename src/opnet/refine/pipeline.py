"""The refinement of an image's hypotheses: ICP (:mod:`opnet.refine.icp`, by an association of
:mod:`opnet.refine.associations`) and, with ``refine=search``, the search.

:func:`refine_hypotheses` refines an image's hypotheses best score first within a time budget
(``budget_ms``; the rest keep their pose, status ``budget``). With ``search`` settings
(``refine=search``) each refined hypothesis then goes through the depth-agreement search of
:mod:`opnet.refine.search` (turns and shifts ICP cannot tell apart on a flat part), is polished
by ICP again and scored by its agreement; duplicates the searches made are dropped.
:func:`refine_image` does it for one depth image, :class:`Refiner` for one object's images.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np

from opnet.geometry.pose_numpy import pose_distance
from opnet.refine.agreement import score_poses
from opnet.refine.associations import refine_poses_nearest, refine_poses_projective
from opnet.refine.clouds import ModelCloud, SceneCloud
from opnet.refine.icp import ICPResult
from opnet.refine.search import ambiguity_turns, model_axis, resolve_mode, search_any_many, search_poses
from opnet.refine.settings import ICPSettings


def refine_hypotheses(R: np.ndarray, t: np.ndarray, score: np.ndarray, model: ModelCloud, scene: SceneCloud,
                      space: Any, settings: ICPSettings = ICPSettings(), depth: np.ndarray | None = None,
                      camera: Any = None, timings: dict[str, float] | None = None, rank_model: ModelCloud | None = None,
                      ) -> tuple[np.ndarray, np.ndarray, list[str], np.ndarray]:  # fmt: skip
    """Refine the hypotheses of one image, best score first, within ``settings.budget_ms``.

    Args:
        R: (N, 3, 3), t: (N, 3) metres, camera frame; score: (N,).
        depth, camera: the depth image (H, W) and its camera (fx, fy, cx, cy) the scene was made
            from; needed with ``settings.search``.
        timings: if given, the seconds of each stage are added to it (:data:`STAGES`).
        rank_model: the model points the final agreements are measured on (``search.rank_points``; None: ``model``).
    Returns:
        refined R (N, 3, 3), t (N, 3) in the input order, each one's status, and its score: the
        input's, or with ``settings.search`` the one its ``score`` setting names (a hypothesis the
        budget left unrefined: its agreement where it stands); status ``suppressed``: a duplicate
        the search made (``search.suppress``), which :func:`refine_image` leaves out.
    """
    R_out, t_out = np.array(R, np.float64, copy=True), np.array(t, np.float64, copy=True)
    score_in = np.asarray(score, np.float64)
    status = ["budget"] * len(R_out)
    search = settings.search
    if search is not None and (depth is None or camera is None):
        raise ValueError("icp: the search needs the depth image and its camera")
    mode = resolve_mode(search, model.points) if search is not None else None
    if mode == "turn" and search.turn_tolerance is not None:
        search = dataclasses.replace(search, tolerance=search.turn_tolerance)
    axis = model_axis(model.points, search.axis) if mode == "turn" else None
    flips = ambiguity_turns(model.points, space) if mode == "flips" else None
    merged = _merged(t_out, score_in, search.merge * model.diameter) if search is not None else np.zeros(len(t_out), bool)
    order = [int(k) for k in np.argsort(-score_in, kind="stable") if not merged[k]]
    for k in np.flatnonzero(merged):
        status[k] = "suppressed"
    polish = settings if settings.polish_association is None else \
        dataclasses.replace(settings, association=settings.polish_association)  # fmt: skip
    threaded = settings.budget_ms is None and settings.threads > 1 and len(order) > 1
    clock = _Stages(timings)
    searched = np.full(len(R_out), -np.inf)  # each searched hypothesis's agreement after the search
    kept_icp: list[int] = []  # hypotheses searched so far (suppress_icp compares with their ICP poses)
    kept_searched: list[int] = []  # ... and polished so far (suppress_searched compares with them)

    def each(stage: str, fn: Any, ks: list[int]) -> None:
        """``fn(share, workers)`` over the hypotheses ``ks``: without a time budget in ``settings.threads``
        shares side by side (each hypothesis's result is what it gets alone), else all at once; timed."""
        if not ks:
            return
        clock.start()
        if threaded and len(ks) > 1:
            parts = [ks[i :: settings.threads] for i in range(min(settings.threads, len(ks)))]
            with ThreadPoolExecutor(len(parts)) as pool:
                for done in [pool.submit(fn, part, 1) for part in parts]:
                    done.result()
        else:
            fn(ks, -1)
        clock.stop(stage)

    starts: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def icp(ks: list[int], workers: int) -> None:
        for k in ks:
            starts[k] = (R_out[k].copy(), t_out[k].copy())
        for k, result in zip(ks, _refine_many(R_out[ks], t_out[ks], model, scene, space, settings, workers),
                             strict=True):  # fmt: skip
            R_out[k], t_out[k], status[k] = result.R, result.t, result.status

    def search_many(ks: list[int], workers: int) -> None:
        if mode == "turn":
            Rs, ts, sc = search_poses(R_out[ks], t_out[ks], model, depth, camera, axis, search)
        else:
            # from the refined pose and from the hypothesis itself: ICP may have pulled a turned hypothesis
            # further off
            Rs, ts, sc = search_any_many(np.stack([(R_out[k], starts[k][0]) for k in ks]),
                                         np.stack([(t_out[k], starts[k][1]) for k in ks]), model, depth, camera,
                                         space, search, flips)  # fmt: skip
        R_out[ks], t_out[ks], searched[ks] = Rs, ts, sc

    def polish_many(ks: list[int], workers: int) -> None:
        for k, result in zip(ks, _refine_many(R_out[ks], t_out[ks], model, scene, space, polish, workers),
                             strict=True):  # fmt: skip
            R_out[k], t_out[k], status[k] = result.R, result.t, "searched"

    def drop_copies(ks: list[int], kept: list[int], radius: float) -> list[int]:
        """Those of ``ks`` (best first) not within ``radius`` δ of a pose kept before them (``kept``, extended
        by them); the others' status ``suppressed``. Timed as ranking."""
        clock.start()
        out = []
        for k in ks:
            if radius > 0 and kept and (pose_distance(space, R_out[k], t_out[k], R_out[kept], t_out[kept])
                                        < radius * space.delta).any():  # fmt: skip
                status[k] = "suppressed"
            else:
                kept.append(k)
                out.append(k)
        clock.stop("rank")
        return out

    # hypotheses go in chunks, best first: all in one without a time budget; under one, a chunk at a time
    # (nearest-point ICP: one hypothesis, as the budget always counted)
    chunk = len(order) if settings.budget_ms is None else PROJECTIVE_CHUNK if settings.association == "projective" \
        else 1  # fmt: skip
    start, best = time.perf_counter(), -np.inf  # best: the best searched agreement so far
    for c0 in range(0, len(order), max(chunk, 1)):
        if settings.budget_ms is not None and (time.perf_counter() - start) * 1000 >= settings.budget_ms:
            break
        ks = order[c0 : c0 + chunk]
        each("icp", icp, ks)
        if search is None:
            continue
        ks = [k for k in ks if status[k] != "no_depth"]
        ks = drop_copies(ks, kept_icp, search.suppress_icp)
        each("search", search_many, ks)
        if search.suppress_searched:
            ks = sorted(ks, key=lambda k: -searched[k])  # stable: equal agreements keep the network's order
            ks = drop_copies(ks, kept_searched, search.suppress)
        if search.polish_share > 0 and ks:
            best = max(best, max(searched[k] for k in ks))
            for k in ks:
                if searched[k] < search.polish_share * best:
                    status[k] = "unpolished"
            ks = [k for k in ks if status[k] != "unpolished"]
        each("polish", polish_many, ks)
    merged = np.array([s == "suppressed" for s in status], bool)
    if search is None:
        return R_out, t_out, status, score_in.copy()
    clock.start()
    agree = np.full(len(R_out), -np.inf)
    if (~merged).any():
        agree[~merged] = score_poses(R_out[~merged], t_out[~merged], model if rank_model is None else rank_model,
                                     depth, camera, search)  # fmt: skip
    final = {"agreement": agree, "network": score_in.copy(), "product": score_in * np.maximum(agree, 0.0)}[search.score]
    clock.stop("rank")
    # duplicates: searches from nearby hypotheses that ended on one pose
    drop_copies([int(k) for k in np.argsort(-final, kind="stable") if not merged[k]], [], search.suppress)
    return R_out, t_out, status, final


#: the stages of a refinement whose seconds :func:`refine_image` can report: the scene cloud from the depth
#: image, ICP, the search, ICP of the search's poses, scoring and ranking
STAGES = ("scene", "icp", "search", "polish", "rank")


class _Stages:
    """Adds the seconds of each stage to a dict (nothing when it is None)."""

    def __init__(self, timings: dict[str, float] | None) -> None:
        self.timings, self.t0 = timings, 0.0

    def start(self) -> None:
        self.t0 = time.perf_counter()

    def stop(self, stage: str) -> None:
        if self.timings is not None:
            self.timings[stage] = self.timings.get(stage, 0.0) + time.perf_counter() - self.t0

    def __call__(self, stage: str, fn: Any, *args: Any) -> Any:
        self.start()
        out = fn(*args)
        self.stop(stage)
        return out


#: hypotheses per batch of projective ICP under a time budget
PROJECTIVE_CHUNK = 8


def _refine_many(R: np.ndarray, t: np.ndarray, model: ModelCloud, scene: SceneCloud, space: Any,
                 settings: ICPSettings, workers: int = -1) -> list[ICPResult]:  # fmt: skip
    """ICP of poses (N, 3, 3), (N, 3) in one batch, projective or nearest-point (``workers``: the k-d tree's)."""
    if settings.association == "projective":
        return refine_poses_projective(R, t, model, scene, space, settings)
    return refine_poses_nearest(R, t, model, scene, space, settings, workers)


def _merged(t: np.ndarray, score: np.ndarray, radius: float) -> np.ndarray:
    """(N,) bool: the hypotheses whose origin (N, 3) lies within ``radius`` metres of a better-scored kept
    one's (greedy, best score first; ties: the earlier); none for ``radius`` 0."""
    out = np.zeros(len(t), bool)
    if radius <= 0 or len(t) < 2:
        return out
    kept: list[int] = []
    for k in np.argsort(-np.asarray(score, np.float64), kind="stable"):
        if kept and (np.linalg.norm(t[kept] - t[k], axis=1) < radius).any():
            out[k] = True
        else:
            kept.append(int(k))
    return out


@functools.cache
def _blas_controller() -> Any:
    """threadpoolctl's controller of the loaded BLAS libraries (None without threadpoolctl), made once."""
    try:
        from threadpoolctl import ThreadpoolController
    except ImportError:  # the torch-free runtime's minimal install: BLAS as configured
        return None
    return ThreadpoolController()


def serial_blas() -> contextlib.AbstractContextManager:
    """A context in which numpy's matrix products run on one thread. The refinement's products are small (a few
    hundred points by 3 per pose): threads cost more than they give, and far more when another process keeps a
    core busy (they wait for it). On 2 cores beside a busy process the search took half the CPU time this way."""
    controller = _blas_controller()
    return contextlib.nullcontext() if controller is None else controller.limit(limits=1, user_api="blas")


def refine_image(hypotheses: Any, depth: np.ndarray, camera: Any, model: ModelCloud, space: Any,
                 settings: ICPSettings = ICPSettings(), timings: dict[str, float] | None = None,
                 rank_model: ModelCloud | None = None) -> tuple[Any, list[str]]:  # fmt: skip
    """The hypotheses of one image (a :class:`opnet.metrics.records.HypothesisSet`) refined against
    its depth image (metres, (H, W)) seen by ``camera`` (fx, fy, cx, cy): (a new set, statuses);
    ``timings``: the seconds of each of :data:`STAGES` added to it; ``rank_model``: :func:`refine_hypotheses`'."""
    if depth.shape != (camera.height, camera.width):
        raise ValueError(f"icp: depth of shape {depth.shape} does not match the camera ({camera.height}, {camera.width})")
    with serial_blas():
        scene = _Stages(timings)("scene", SceneCloud.from_depth, depth, camera.fx, camera.fy, camera.cx, camera.cy,
                                 settings.stride)  # fmt: skip
        # the search scores in float32 (:func:`opnet.refine.agreement.agreement`): depth to a tenth of a micron
        R, t, status, score = refine_hypotheses(hypotheses.R, hypotheses.t, hypotheses.score, model, scene, space,
                                                settings, np.asarray(depth, np.float32), camera, timings,
                                                rank_model)  # fmt: skip
    keep = np.array([s != "suppressed" for s in status], bool)
    visibility = None if hypotheses.visibility is None else np.asarray(hypotheses.visibility)[keep]
    return type(hypotheses)(R[keep], t[keep], score[keep], visibility), status


@dataclass(frozen=True)
class Refiner:
    """ICP for one object: its model cloud, pose space and settings, ready for images; ``rank_model``: the
    points its final agreements are measured on (``search.rank_points``; None: ``model``'s)."""

    model: ModelCloud
    space: Any
    settings: ICPSettings
    rank_model: ModelCloud | None = None

    @classmethod
    def for_object(cls, obj: Any, settings: ICPSettings) -> Refiner:
        """From an :class:`opnet.objects.model.ObjectModel` (it needs its mesh)."""
        from opnet.geometry.pose_numpy import PoseSpaceArrays

        if obj.mesh is None:
            raise ValueError(f"icp: object {obj.name!r} has no mesh to refine against")
        return cls(ModelCloud.from_mesh(obj.mesh, settings.model_points, obj.diameter),
                   PoseSpaceArrays.of(obj.pose_space), settings, rank_cloud(obj.mesh, obj.diameter, settings))

    def __call__(self, hypotheses: Any, depth: np.ndarray, camera: Any,
                 timings: dict[str, float] | None = None) -> tuple[Any, list[str]]:  # fmt: skip
        """:func:`refine_image` with this object's model."""
        return refine_image(hypotheses, depth, camera, self.model, self.space, self.settings, timings, self.rank_model)


def rank_cloud(mesh: Any, diameter: float, settings: ICPSettings) -> ModelCloud | None:
    """The model points ``settings``' final agreements are measured on (``search.rank_points`` of them, sampled
    apart from ICP's), or None where they are ICP's own."""
    if settings.search is None or not settings.search.rank_points:
        return None
    return ModelCloud.from_mesh(mesh, settings.search.rank_points, diameter, seed=1)


__all__ = ["STAGES", "Refiner", "rank_cloud", "refine_hypotheses", "refine_image", "serial_blas"]
