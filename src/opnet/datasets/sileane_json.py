"""Siléane / Brégier JSON files: per-scene ground truth and pose hypotheses
(docs/formats.md#siléane-layout).

Ground truth, one file per scene: a JSON list of
``{"R": 3x3 nested rows, "t": [x, y, z], "occlusion_rate": float, "segmentation_id": int}``.
Results, one file ``<scene>.json`` per scene: a JSON list of ``{"R", "t", "score"}`` (higher score
= more confident; an optional ``"visibility"`` is kept). ``x_frame = R x_obj + t``, metres; the
frame is whatever the ground truth uses (world for Siléane, camera for IPA) and must be the same
on both sides.

Readers validate everything and raise ``ValueError`` naming the file, the entry and the problem;
writers are atomic (temporary file in the same folder, then ``os.replace``).
"""

from __future__ import annotations

import json
import math
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from opnet.datasets.validate import check_poses, check_range
from opnet.fileio.atomic import write_text_atomic
from opnet.fileio.files import read_json
from opnet.metrics.records import GroundTruthSet, HypothesisSet

#: segmentation ids are the instances' values in the 16-bit segmentation image
MAX_SEGMENTATION_ID = 65535
JSON_SUFFIXES = (".json", ".JSON")


def read_gt_json(path: str | Path) -> GroundTruthSet:
    """Read one scene's ground truth.

    Args:
        path: a Siléane ground-truth file (list of {R, t, occlusion_rate, segmentation_id}).
    Returns:
        R (N, 3, 3) float64, t (N, 3) float64 metres, occlusion_rate (N,) float64, segmentation_id
        (N,) int64 (1..N when the file has none).
    Raises:
        FileNotFoundError: the file cannot be read. ValueError: malformed content (names the file).
    """
    path = Path(path)
    entries = _read_list(path)
    R, t = _poses(entries, path)
    occ = _floats(entries, "occlusion_rate", path)
    check_range(occ, 0.0, 1.0, "'occlusion_rate'", lambda i: f"{path}: entry {i}")
    has_id = ["segmentation_id" in e for e in entries]
    if any(has_id) and not all(has_id):
        i = has_id.index(False)
        raise ValueError(f"{path}: entry {i}: missing key 'segmentation_id' (other entries have it)")
    ids = [_int(e["segmentation_id"], path, i) for i, e in enumerate(entries)] if all(has_id) else []
    seg = np.array(ids, dtype=np.int64)
    return GroundTruthSet(R, t, occ, seg)


def read_results_json(path: str | Path) -> HypothesisSet:
    """Read one scene's pose hypotheses.

    Args:
        path: a results file (list of {R, t, score}); ``[]`` means no hypotheses.
    Returns:
        R (N, 3, 3) float64, t (N, 3) float64 metres, score (N,) float64, visibility (N,) or None.
    Raises:
        FileNotFoundError: the file cannot be read. ValueError: malformed content (names the file).
    """
    path = Path(path)
    entries = _read_list(path)
    if not entries:
        return HypothesisSet.empty()
    R, t = _poses(entries, path)
    score = _floats(entries, "score", path)
    has_vis = ["visibility" in e for e in entries]
    vis = _floats(entries, "visibility", path) if all(has_vis) else None
    return HypothesisSet(R, t, score, vis)


def write_gt_json(path: str | Path, gt: GroundTruthSet) -> None:
    """Write one scene's ground truth in the Siléane format (atomic; creates the parent folder)."""
    entries = [
        {"R": R.tolist(), "t": t.tolist(), "occlusion_rate": float(o), "segmentation_id": int(s)}
        for R, t, o, s in zip(gt.R, gt.t, gt.occlusion_rate, gt.segmentation_id, strict=True)
    ]
    write_json_atomic(Path(path), entries)


def write_results_json(path: str | Path, hyps: HypothesisSet) -> None:
    """Write one scene's hypotheses as ``[{R, t, score[, visibility]}]``.

    Atomic; creates the parent folder.
    """
    entries: list[dict[str, Any]] = []
    for i in range(len(hyps)):
        e: dict[str, Any] = {"R": hyps.R[i].tolist(), "t": hyps.t[i].tolist()}
        e["score"] = float(hyps.score[i])
        if hyps.visibility is not None:
            e["visibility"] = float(hyps.visibility[i])
        entries.append(e)
    write_json_atomic(Path(path), entries)


def scene_files(folder: str | Path) -> dict[str, Path]:
    """Scene name -> file for every ``*.json`` / ``*.JSON`` in a folder (not recursive), by name.

    Raises:
        FileNotFoundError: the folder does not exist. ValueError: two files give the same scene name.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: folder not found")
    out: dict[str, Path] = {}
    for p in sorted(folder.iterdir()):
        if p.suffix in JSON_SUFFIXES and p.is_file():
            if p.stem in out:
                clash = f"{out[p.stem].name}, {p.name}"
                raise ValueError(f"{folder}: scene {p.stem!r} appears twice ({clash})")
            out[p.stem] = p
    return out


class SceneFileWarning(UserWarning):
    """A scene has a file on one side only (ground truth without results, or the reverse)."""


def read_scene_pairs(
    gt_dir: str | Path, results_dir: str | Path, skip_missing: bool = False
) -> dict[str, tuple[GroundTruthSet, HypothesisSet]]:
    """Pair every ground-truth file with the results file of the same scene name.

    A scene with ground truth but no results file counts as a scene with no hypotheses (recall 0
    where there is something to find), with a :class:`SceneFileWarning`; ``skip_missing=True``
    drops it instead, as the official tool does (docs/method.md#evaluation). A results file
    without ground truth is ignored with a warning.

    Returns:
        scene name -> (ground truth, hypotheses), sorted by name.
    """
    gts, results = scene_files(gt_dir), scene_files(results_dir)
    orphans = sorted(set(results) - set(gts))
    if orphans:
        warnings.warn(
            f"{results_dir}: {len(orphans)} results file(s) without ground truth in {gt_dir}, ignored: "
            f"{_names(orphans)}", SceneFileWarning, stacklevel=2,
        )
    missing = sorted(set(gts) - set(results))
    if missing:
        action = "skipped (--skip-missing)" if skip_missing else "counted as scenes with no hypotheses"
        warnings.warn(
            f"{results_dir}: no results file for {len(missing)} scene(s), {action}: {_names(missing)}",
            SceneFileWarning, stacklevel=2,
        )
    pairs: dict[str, tuple[GroundTruthSet, HypothesisSet]] = {}
    for name, gt_path in gts.items():
        if name in results:
            pairs[name] = (read_gt_json(gt_path), read_results_json(results[name]))
        elif not skip_missing:
            pairs[name] = (read_gt_json(gt_path), HypothesisSet.empty())
    return pairs


def _names(names: Sequence[str], limit: int = 10) -> str:
    shown = ", ".join(names[:limit])
    return shown + (f", ... ({len(names) - limit} more)" if len(names) > limit else "")


# ---- reading helpers ---------------------------------------------------------------------------
def _read_list(path: Path) -> list[dict[str, Any]]:
    data = read_json(path, "a list of pose objects")
    if not isinstance(data, list):
        raise ValueError(f"{path}: expected a JSON list of poses, got a JSON {type(data).__name__}")
    for i, e in enumerate(data):
        if not isinstance(e, dict):
            raise ValueError(f"{path}: entry {i}: expected a JSON object, got {type(e).__name__}")
    return data


def _field(entry: dict[str, Any], key: str, path: Path, i: int) -> Any:
    if key not in entry:
        raise ValueError(f"{path}: entry {i}: missing key {key!r} (has {sorted(entry)})")
    return entry[key]


def _array(value: Any, shape: tuple[int, ...], key: str, path: Path, i: int) -> np.ndarray:
    try:
        a = np.array(value, dtype=np.float64)
    except (ValueError, TypeError):
        a = None
    if a is None or a.shape != shape or _has_bool(value):
        got = _describe(value)
        raise ValueError(f"{path}: entry {i}: {key!r} must be numbers of shape {shape}, got {got}")
    if not np.isfinite(a).all():
        raise ValueError(f"{path}: entry {i}: {key!r} contains NaN or inf")
    return a


def _poses(entries: Sequence[dict[str, Any]], path: Path) -> tuple[np.ndarray, np.ndarray]:
    if not entries:
        return np.zeros((0, 3, 3)), np.zeros((0, 3))
    R = np.stack([_array(_field(e, "R", path, i), (3, 3), "R", path, i) for i, e in enumerate(entries)])
    t = np.stack([_array(_field(e, "t", path, i), (3,), "t", path, i) for i, e in enumerate(entries)])
    check_poses(R, t, lambda i: f"{path}: entry {i}")
    return R, t


def _floats(entries: Sequence[dict[str, Any]], key: str, path: Path) -> np.ndarray:
    values = [_array(_field(e, key, path, i), (), key, path, i) for i, e in enumerate(entries)]
    return np.array(values, dtype=np.float64)


def _int(value: Any, path: Path, i: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int | float) or not float(value).is_integer():
        got = _describe(value)
        raise ValueError(f"{path}: entry {i}: 'segmentation_id' must be an integer, got {got}")
    if not 0 <= value <= MAX_SEGMENTATION_ID:
        raise ValueError(f"{path}: entry {i}: 'segmentation_id' = {_describe(value)} is outside 0..{MAX_SEGMENTATION_ID} "
                         "(the 16-bit value of the instance in the segmentation image)")
    return int(value)


def _has_bool(value: Any) -> bool:
    if isinstance(value, bool):
        return True
    return isinstance(value, list) and any(_has_bool(v) for v in value)


def _describe(value: Any) -> str:
    text = json.dumps(value) if not isinstance(value, float) or math.isfinite(value) else str(value)
    return text if len(text) <= 60 else text[:57] + "..."


# ---- writing -----------------------------------------------------------------------------------
def write_json_atomic(path: str | Path, data: Any) -> None:
    """Write JSON data to ``path`` atomically (see :mod:`opnet.fileio.atomic`).

    Raises:
        ValueError: the data holds NaN or inf (not valid JSON); nothing is written.
    """
    try:
        text = json.dumps(data, allow_nan=False)
    except ValueError as e:
        raise ValueError(f"{path}: refusing to write NaN or inf ({e})") from None
    write_text_atomic(path, text)
