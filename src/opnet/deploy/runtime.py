"""Run an exported model without PyTorch: preprocess -> ONNX Runtime -> decode -> averaging.

    from opnet.deploy.runtime import OnnxPoseEstimator
    estimator = OnnxPoseEstimator("model.onnx")
    hyps = estimator.predict(depth_m, camera)   # (H, W) metres, NaN = none; opnet.geometry.camera.Camera
    hyps.R, hyps.t, hyps.score                  # camera frame, metres, best first not guaranteed

Imports numpy, OpenCV, SciPy and onnxruntime only: this module, the preprocessing
(:mod:`opnet.data.preprocess`), the camera, the hypothesis records and the averaging load without
PyTorch (``tests/unit/test_deploy.py`` runs it with ``import torch`` made to fail). The steps after
the graph are those of ``Parameterization.decode``: cells whose presence exceeds the threshold
(and whose visibility reaches ``min_visibility``) become hypotheses scored by ``p``, ``p*v`` or
``v``, then the DBSCAN pose averaging of :class:`opnet.parameterizations.averaging.PoseAveraging`.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from opnet._limits import check_threads
from opnet.data.preprocess import to_network_input
from opnet.data.roi import crop_image, parse_roi
from opnet.deploy.metadata import OUTPUTS, QUALITY_OUTPUT, validate_metadata
from opnet.fileio.files import require_regular_file
from opnet.geometry.camera import Camera, with_clip, working_clip
from opnet.geometry.frames import BASE_POSE_KEY
from opnet.geometry.pose_numpy import PoseSpaceArrays
from opnet.metrics.records import HypothesisSet
from opnet.parameterizations.averaging import PoseAveraging
from opnet.parameterizations.turns import quarters, turned_back, turned_camera
from opnet.refine import ICPSettings, ModelCloud, Refiner, search_settings
from opnet.run_settings import REFINE_NAMES, DecodingSettings, InputSettings
from opnet.settings_schema import QUALITY_SCORES, hypothesis_score

METADATA_KEY = "opnet"

_INTERPOLATION = {"area": cv2.INTER_AREA}


def recorded_refinement(name: str | None, budget_ms: float | None = None) -> ICPSettings | None:
    """The settings of a refinement named as an export records it, the runtime's flags too: ``icp``
    (``--icp``; 100 ms per image unless ``budget_ms``), ``search`` (``--search``), ``search_fast``
    (``--search-fast``), ``search_flat`` (all three without a budget unless ``budget_ms``); None: none."""
    if name is None:
        return None
    if name == "icp":
        return ICPSettings(budget_ms=100.0 if budget_ms is None else budget_ms)
    if name in REFINE_NAMES:  # every other recordable refinement runs the search: its own conf/refine file
        return search_settings(budget_ms, name)
    raise ValueError(f"refinement {name!r}: the runtime runs {', '.join(REFINE_NAMES)}")


class OnnxPoseEstimator:
    """An exported opnet model in ONNX Runtime (CPU by default).

    Args:
        path: the ``.onnx`` file written by ``python export.py``.
        providers: ONNX Runtime execution providers (default: CPU).
        threads: intra-op threads (default: ONNX Runtime's choice, one per core).
        icp: ICP (and search) settings to refine with, None for none, or "model" (the default): the
            refinement the export records (:func:`recorded_refinement`; none if it records none). roi:
            the region of interest ("model": the exported one). averaging: False decodes without the
            exported DBSCAN averaging (as ``eval.py +decoding.averaging=false``; with the search, every
            hypothesis is a start), True with it, None (the default) as the model is meant to run:
            without it where the refinement the export records is the search, else with it (the decoding's
            ``turns``: the image alone before any search, else the exported turns). clip: the
            clip planes an input's depth is normalized with: "model" (the
            training scenes' planes the export records; the camera's if it records none), "camera"
            (each camera's own) or (near, far) metres.
    Raises:
        FileNotFoundError: no such file.
        ValueError: not an ONNX model, no opnet metadata, or metadata that contradicts the graph
            (the message names the file).
    """

    def __init__(self, path: str | Path, providers: Sequence[str] = ("CPUExecutionProvider",),
                 threads: int | None = None, icp: ICPSettings | str | None = "model", roi: Any = "model",
                 averaging: bool | None = None, clip: Any = "model") -> None:
        import onnxruntime as ort

        self.path = Path(path)
        if not self.path.exists():
            raise FileNotFoundError(f"{self.path}: ONNX model not found")
        require_regular_file(self.path)  # a FIFO or /dev/zero is named as such (and never read)
        options = ort.SessionOptions()
        if threads is not None:
            options.intra_op_num_threads = check_threads(threads)
        try:
            self.session = ort.InferenceSession(str(self.path), options, providers=list(providers))
        except Exception as e:  # onnxruntime raises its own exception types for foreign files
            raise ValueError(f"{self.path}: not a loadable ONNX model ({type(e).__name__}: {str(e)[:200]})") from None
        raw = self.session.get_modelmeta().custom_metadata_map.get(METADATA_KEY)
        if raw is None:
            raise ValueError(f"{self.path}: no opnet metadata (key {METADATA_KEY!r}); export it with python export.py")
        try:
            self.meta: dict[str, Any] = json.loads(raw)
        except (json.JSONDecodeError, RecursionError) as e:
            raise ValueError(f"{self.path}: opnet metadata is not JSON ({str(e)[:200]})") from None
        self.settings = validate_metadata(self.meta, self.path)
        self._check_graph()
        s = self.settings
        #: the exported framing and decoding (:mod:`opnet.run_settings`)
        self.input: InputSettings = s["input"]
        self.decoding: DecodingSettings = s["decoding"]
        d = self.decoding
        self.threshold, self.score, self.min_visibility = d.threshold, d.score, d.min_visibility
        ps = s["pose_space"]
        space = PoseSpaceArrays(ps["Lambda"], ps["group"], ps["delta"], ps["revolution"], ps["lam"])
        #: the refinement the export records (train.py's deploy_refine), or None
        self.recorded_refine: str | None = s["refine"]
        #: the training camera's pose in the robot's base frame (4 x 4, camera to base) the export
        #: records, or None (:func:`opnet.geometry.frames.camera_to_base` takes it)
        self.T_base_cam: np.ndarray | None = None if s[BASE_POSE_KEY] is None else np.array(s[BASE_POSE_KEY])
        #: the training scenes' camera the export records (:data:`opnet.run_settings.CAMERA_KEYS`), or None
        self.camera: tuple[float, ...] | None = s["camera"]
        by_model = isinstance(icp, str) and icp == "model"
        icp = recorded_refinement(self.recorded_refine) if by_model else icp
        searched = icp is not None and icp.search is not None
        if averaging is None:
            averaging = not (by_model and searched)
        #: the input's turns pooled (the decoding's; 1 before a search, as eval.py decodes for it)
        self.turns = 1 if searched else self.decoding.turns
        avg = d.averaging
        self.averaging = None if avg is None or not averaging else PoseAveraging(space, avg.eps, avg.min_samples,
                                                                avg.cluster_score, avg.keep_noise)
        self.input_size = self.input.size
        self.fit = self.input.fit
        self.roi = self.input.roi if roi == "model" else parse_roi(roi, "roi")
        self.trained_clip: tuple[float, float] | None = self.input.trained_clip
        self.clip = working_clip(clip, self.trained_clip)
        self.refiner: Refiner | None = None
        if icp is not None:
            cloud = s["icp_model"]
            if cloud is None:
                raise ValueError(f"{self.path}: no ICP model points in its metadata; export it again with python export.py")
            rank = None
            if icp.search is not None and icp.search.rank_points:
                if len(cloud.get("rank_points", ())) != icp.search.rank_points:
                    raise ValueError(f"{self.path}: the refinement ranks on {icp.search.rank_points} model points of "
                                     "its own (search.rank_points), not in its metadata; export it again with "
                                     "python export.py")  # fmt: skip
                rank = ModelCloud(cloud["rank_points"], cloud["rank_normals"], cloud["diameter"])
            self.refiner = Refiner(ModelCloud(cloud["points"], cloud["normals"], cloud["diameter"]), space, icp, rank)

    def _check_graph(self) -> None:
        """The graph's inputs and outputs are those the (validated) metadata describes."""
        m, s = self.meta, self.settings
        names = [o.name for o in self.session.get_outputs()]
        if names != list(m["outputs"]):
            raise ValueError(f"{self.path}: graph outputs {names} differ from the metadata's outputs {m['outputs']}")
        if names not in (list(OUTPUTS), [*OUTPUTS, QUALITY_OUTPUT]):
            raise ValueError(f"{self.path}: graph outputs {names}: expected {list(OUTPUTS)}, and {QUALITY_OUTPUT!r} "
                             "after them from a network with a quality channel")
        if s["decoding"].score in QUALITY_SCORES and QUALITY_OUTPUT not in names:
            raise ValueError(f"{self.path}: decoding.score={s['decoding'].score!r} reads the quality channel q, and "
                             f"the graph has no {QUALITY_OUTPUT!r} output")
        cells = s["slots"] * s["grid_size"] ** 2
        shape = self.session.get_outputs()[0].shape  # (batch, N)
        if len(shape) != 2 or shape[1] != cells:
            raise ValueError(f"{self.path}: the graph decodes {shape[1] if len(shape) == 2 else '?'} cells, but the "
                             f"metadata's {m['parameterization'][:40]} parameterization has {s['slots']} "
                             f"slot(s) x {s['grid_size']}^2 = {cells}: graph and metadata do not belong together")
        size = self.session.get_inputs()[0].shape
        if size[2:] != [s["input_size"], s["input_size"]]:
            raise ValueError(f"{self.path}: graph input {size} does not match the metadata's input.size {s['input_size']}")

    # ---- the pipeline ------------------------------------------------------------------------
    def preprocess(self, depth: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
        """(1, 1, S, S) float32 network input and (1, 8) float64 input camera of one image."""
        depth, camera = crop_image(np.asarray(depth, dtype=np.float32), camera, self.roi, "roi")
        image, cam = to_network_input(depth, camera, size=self.input_size,
                                      interpolation=_INTERPOLATION[self.input.interpolation],
                                      fit=self.fit)
        return image[None, None].astype(np.float32), np.asarray([cam.row()], dtype=np.float64)

    def run(self, images: np.ndarray, cameras: np.ndarray) -> tuple[np.ndarray, ...]:
        """The graph on a batch: (presence, visibility, translation, rotation) of every cell. With the decoding's
        ``turns`` 2 or 4, the graph also runs on the images turned by each other quarter turn (their cameras
        turned with them, :mod:`opnet.parameterizations.turns`), and each image's cells of every turn follow
        one another, their poses turned back into the image's camera."""
        outs = [tuple(self.session.run(None, {"depth": images, "camera": cameras}))]
        for q in quarters(self.turns)[1:]:
            turned = np.ascontiguousarray(np.rot90(images, q, axes=(-2, -1)))
            rows = np.asarray([turned_camera(Camera.from_row(r), q).row() for r in cameras], dtype=np.float64)
            presence, visibility, t, R, *quality = self.session.run(None, {"depth": turned, "camera": rows})
            R, t = turned_back(R, t, q)
            outs.append((presence, visibility, t, R, *quality))
        return tuple(np.concatenate(x, axis=1) for x in zip(*outs, strict=True))

    def decode(self, presence: np.ndarray, visibility: np.ndarray, t: np.ndarray, R: np.ndarray,
               quality: np.ndarray | None = None) -> HypothesisSet:
        """Hypotheses of one image from its dense outputs (N,), (N,), (N, 3), (N, 3, 3) and, from a network with a
        quality channel, (N,) (with ``turns``, the cells of each turn one after the other, as :meth:`run` gives
        them)."""
        passes = len(quarters(self.turns))
        keep = np.concatenate([self._kept(p, v) for p, v in zip(np.split(presence, passes),
                                                                  np.split(visibility, passes), strict=True)])
        p, v = presence[keep], visibility[keep]
        score = hypothesis_score(self.score, p, v, None if quality is None else quality[keep])
        hyps = HypothesisSet(R[keep], t[keep], score, v)
        return self.averaging(hyps) if self.averaging is not None else hyps

    def _kept(self, presence: np.ndarray, visibility: np.ndarray) -> np.ndarray:
        """The cells of one pass that become hypotheses: presence above the threshold, visibility enough."""
        keep = presence > self.threshold
        if self.settings["slot_conditional"]:  # slot l + 1 counts only where slots 1..l are present (slot-major cells)
            slots = self.settings["slots"]
            keep = np.minimum.accumulate(keep.reshape(slots, -1), axis=0).reshape(-1)
        if self.min_visibility > 0:
            keep &= visibility >= self.min_visibility
        return keep

    def predict(self, depth: np.ndarray, camera: Camera) -> HypothesisSet:
        """Pose hypotheses of one depth image ((H, W) metres, NaN = missing) in its camera frame."""
        camera = with_clip(camera, self.clip)
        image, cam = self.preprocess(depth, camera)
        return self.refine(self.decode(*(o[0] for o in self.run(image, cam))), depth, camera)

    def refine(self, hyps: HypothesisSet, depth: np.ndarray, camera: Camera) -> HypothesisSet:
        """The hypotheses refined by ICP against the depth when the estimator has ``icp`` settings."""
        return hyps if self.refiner is None else self.refiner(hyps, np.asarray(depth, np.float64), camera)[0]

    def predict_batch(self, depths: Sequence[np.ndarray], cameras: Sequence[Camera]) -> list[HypothesisSet]:
        """Several images in one graph run (faster per image on a CPU)."""
        cameras = [with_clip(c, self.clip) for c in cameras]
        pairs = [self.preprocess(d, c) for d, c in zip(depths, cameras, strict=True)]
        if not pairs:
            return []
        outs = self.run(np.concatenate([p[0] for p in pairs]), np.concatenate([p[1] for p in pairs]))
        return [self.refine(self.decode(*(o[i] for o in outs)), depths[i], cameras[i]) for i in range(len(pairs))]


