"""The BOP format (Hodaň et al., bop.felk.cvut.cz): reader, symmetry mapping, writer, results CSV.

Layout of a BOP dataset (what is read; units are millimetres in BOP, metres inside opnet)::

    <dataset>/models/models_info.json     per obj_id: diameter (mm), symmetries_discrete (4x4, mm),
                                          symmetries_continuous ({axis, offset (mm)})
    <dataset>/models/obj_XXXXXX.ply       the meshes, mm
    <dataset>/<split>/XXXXXX/             one folder per scene (6-digit scene id)
        scene_camera.json                 per image id: cam_K (3x3 row-wise), depth_scale (depth
                                          unit in mm), optional cam_R_w2c / cam_t_w2c
        scene_gt.json                     per image id: [{obj_id, cam_R_m2c (row-wise), cam_t_m2c (mm)}]
        scene_gt_info.json                per image id, same order: [{visib_fract, bbox_obj, ...}]
        depth/XXXXXX.png                  uint16, depth (mm) = value x depth_scale, 0 = no depth
        mask_visib/XXXXXX_YYYYYY.png      visible silhouette of GT instance YYYYYY (optional)

One object id per model, as the paper trains one network per object: instances of the chosen
``obj_id`` are the ground truth, other objects are clutter (background in the segmentation).
Poses go to opnet's model frame, which puts a symmetry axis on z (``R_align``, see
:func:`symmetry_from_bop`); every reader error names the file.
"""

from __future__ import annotations

import json
import math
import os
import re
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from opnet._repr import short_repr
from opnet.datasets.atomic import disk_full_named, write_text_atomic
from opnet.datasets.files import read_json
from opnet.datasets.png import read_png, write_png
from opnet.datasets.record import SceneRecord
from opnet.datasets.validate import check_poses, check_range
from opnet.geometry.camera import Camera
from opnet.geometry.symmetry import MAX_GROUP_SIZE, Symmetry

MODELS_INFO = "models_info.json"
SCENE_FILES = ("scene_camera.json", "scene_gt.json", "scene_gt_info.json")
#: a symmetry whose axis or translation misses the model origin by more than this share of the
#: diameter cannot be expressed as a rotation about the origin (opnet's symmetry groups)
ORIGIN_TOL = 0.01
#: BOP ids name files of 6 digits (``obj_000001.ply``); 0 is no object
MAX_BOP_ID = 999_999
#: a ground-truth translation must lie within these factors of the image's depth range (nearest,
#: farthest valid pixel): ``cam_t_m2c`` in metres instead of millimetres puts every part a thousand
#: times too close
_T_RANGE_FACTORS = (0.5, 2.0)
#: default working range of BOP data without clip planes: these quantiles of the valid depth of
#: the first image, widened by the factors below
_CLIP_QUANTILES, _CLIP_WIDEN = (0.01, 0.99), (0.8, 1.25)


# ------------------------------------------------------------------------------------------ files


def _numbers(value: Any, n: int, key: str, where: str) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        a = np.zeros(0)
    if a.size != n or not np.isfinite(a).all() or _has_bool(value):
        what = "a finite number" if n == 1 else f"{n} finite numbers"
        raise ValueError(f"{where}: '{key}' must be {what}, got {short_repr(value)}")
    return a


def _has_bool(value: Any) -> bool:
    return isinstance(value, bool) or (isinstance(value, list) and any(_has_bool(v) for v in value))


def bop_id(value: Any, key: str, where: str) -> int:
    """A BOP object id (``obj_id``, ``--obj-id``, ``data.object_id``) as an int in 1..999999: a
    whole number, not a boolean or a fraction (``1.9`` is no id, not object 1).

    Raises:
        ValueError: naming ``where`` and ``key``.
    """
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= MAX_BOP_ID:
        raise ValueError(f"{where}: {key}={short_repr(value)} is not a BOP object id (a whole number in "
                         f"1..{MAX_BOP_ID})")
    return value


def _list(value: Any, key: str, where: str) -> list[Any]:
    if not isinstance(value, list):
        raise ValueError(f"{where}: '{key}' must be a list, got {short_repr(value)}")
    return value


def _key(entry: Any, key: str, where: str) -> Any:
    if not isinstance(entry, dict) or key not in entry:
        raise ValueError(f"{where}: missing key '{key}'")
    return entry[key]


# ------------------------------------------------------------------------------------- symmetries


def _rotation_to_z(axis: np.ndarray) -> np.ndarray:
    """A rotation A with A @ axis = z (the identity when the axis already is +z)."""
    a = axis / np.linalg.norm(axis)
    z = np.array([0.0, 0.0, 1.0])
    v, c = np.cross(a, z), float(a @ z)
    if np.linalg.norm(v) < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx * (1 / (1 + c))


def _axis_angle(R: np.ndarray) -> tuple[np.ndarray, float]:
    angle = math.acos(max(-1.0, min(1.0, (np.trace(R) - 1) / 2)))
    if angle > math.pi - 1e-6:  # 180 degrees: the axis from R + I
        M = R + np.eye(3)
        axis = M[:, int(np.argmax(np.linalg.norm(M, axis=0)))]
    else:
        axis = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return axis / max(np.linalg.norm(axis), 1e-12), angle


def symmetry_from_bop(info: dict[str, Any], where: str) -> tuple[Symmetry, np.ndarray]:
    """opnet's symmetry of a BOP ``models_info`` entry, and the alignment ``R_align`` of the model
    frame (``x_opnet = R_align x_bop``) that puts the symmetry axis on z.

    - no symmetries: none;
    - ``symmetries_continuous`` with one axis: revolution about it; a discrete symmetry that turns
      the axis over (e.g. 180 degrees about x for an axis z) adds the end-over-end flip;
    - ``symmetries_discrete`` whose non-identity rotations share one axis and form C_k: cyclic k;
    - other discrete sets: the finite group they form with the identity (closure checked).

    Raises:
        ValueError: naming ``where``: several continuous axes (a sphere), a symmetry that does not
            pass through the model origin (translation or offset > 1 % of the diameter), a
            discrete matrix that is not a rotation, or a set that is not a group.
    """
    if not isinstance(info, dict):
        raise ValueError(f"{where}: expected an object of model info (diameter, symmetries), got a "
                         f"{type(info).__name__}")
    diameter = float(_numbers(info.get("diameter", 0.0) or 0.0, 1, "diameter", where)[0])
    tol = ORIGIN_TOL * diameter if diameter > 0 else 1.0  # mm
    discrete = []
    for i, m in enumerate(_list(info.get("symmetries_discrete") or [], "symmetries_discrete", where)):
        T = _numbers(m, 16, f"symmetries_discrete[{i}]", where).reshape(4, 4)
        R, t = T[:3, :3], T[:3, 3]
        if np.abs(R.T @ R - np.eye(3)).max() > 1e-4 or np.linalg.det(R) < 0:
            raise ValueError(f"{where}: symmetries_discrete[{i}] is not a rotation (a reflection or scaled matrix)")
        if np.linalg.norm(t) > tol:
            raise ValueError(f"{where}: symmetries_discrete[{i}] moves the origin by {np.linalg.norm(t):.3g} mm: opnet's "
                             "symmetries are rotations about the model origin; centre the model on the symmetry axis")
        if np.abs(R - np.eye(3)).max() > 1e-6 and all(np.abs(R - D).max() > 1e-6 for D in discrete):
            discrete.append(R)  # a repeated element is one element of the group
        if len(discrete) > MAX_GROUP_SIZE:
            raise ValueError(f"{where}: symmetries_discrete holds more than {MAX_GROUP_SIZE} distinct rotations: "
                             "not a part's symmetry group")
    continuous = _list(info.get("symmetries_continuous") or [], "symmetries_continuous", where)
    if len(continuous) > 1:
        raise ValueError(f"{where}: {len(continuous)} continuous symmetry axes (a sphere?) cannot be mapped; "
                         "opnet supports one axis of revolution")
    if continuous:
        axis = _numbers(_key(continuous[0], "axis", f"{where}: symmetries_continuous[0]"), 3, "axis", where)
        offset = _numbers(continuous[0].get("offset", [0, 0, 0]), 3, "offset", where)
        if np.linalg.norm(axis) < 1e-9:
            raise ValueError(f"{where}: symmetries_continuous axis is zero")
        # the offset is a point on the axis: only its distance to the axis line matters
        a = axis / np.linalg.norm(axis)
        miss = np.linalg.norm(offset - (offset @ a) * a)
        if miss > tol:
            raise ValueError(f"{where}: the continuous symmetry axis misses the model origin by {miss:.3g} mm; "
                             "centre the model on the axis")
        A = _rotation_to_z(a)
        flip = False
        for R in discrete:
            Rz = A @ R @ A.T
            if Rz[2, 2] < -1 + 1e-6:
                flip = True
            elif Rz[2, 2] < 1 - 1e-6:
                raise ValueError(f"{where}: a discrete symmetry tilts the axis of revolution (neither keeps nor "
                                 "turns it over): cannot be mapped")
        return Symmetry("revolution", rotoreflection=flip), A
    if not discrete:
        return Symmetry("none"), np.eye(3)
    axes_angles = [_axis_angle(R) for R in discrete]
    axis0 = axes_angles[0][0]
    k = len(discrete) + 1
    if all(abs(abs(ax @ axis0) - 1) < 1e-6 for ax, _ in axes_angles):
        steps = [ang / (2 * math.pi / k) for _, ang in axes_angles]
        if all(abs(s - round(s)) < 1e-4 for s in steps):
            return Symmetry("cyclic", order=k), _rotation_to_z(axis0)
    try:
        return Symmetry("finite", rotations=np.stack([np.eye(3), *discrete])), np.eye(3)
    except ValueError as e:
        raise ValueError(f"{where}: symmetries_discrete: {e}") from None


def bop_symmetry_entries(symmetry: Symmetry) -> dict[str, Any]:
    """``symmetries_discrete`` / ``symmetries_continuous`` of a models_info entry for ``symmetry``
    (opnet's model frame, symmetries about the origin)."""
    out: dict[str, Any] = {}
    if symmetry.is_revolution:
        out["symmetries_continuous"] = [{"axis": [0, 0, 1], "offset": [0, 0, 0]}]
        if symmetry.rotoreflection:
            out["symmetries_discrete"] = [_matrix16(np.diag([1.0, -1.0, -1.0]))]
        return out
    group = symmetry.group()
    if len(group) > 1:
        out["symmetries_discrete"] = [_matrix16(R) for R in group[1:]]
    return out


def _matrix16(R: np.ndarray) -> list[float]:
    T = np.eye(4)
    T[:3, :3] = R
    return [float(v) for v in T.reshape(-1)]


# ------------------------------------------------------------------------------------------ models


def models_dir_of(root: Path) -> Path:
    """``<dataset>/models`` for a split folder ``<dataset>/<split>`` (or the dataset folder itself)."""
    for candidate in (root.parent / "models", root / "models"):
        if (candidate / MODELS_INFO).is_file():
            return candidate
    raise FileNotFoundError(f"{root.parent / 'models' / MODELS_INFO}: file not found (a BOP split folder "
                            "<dataset>/<split> needs <dataset>/models/models_info.json)")


def model_info(models_dir: Path, obj_id: int) -> dict[str, Any]:
    path = models_dir / MODELS_INFO
    obj_id = bop_id(obj_id, "obj_id", str(path))
    info = read_json(path)
    if not isinstance(info, dict):
        raise ValueError(f"{path}: expected an object of obj_id -> model info")
    entry = info.get(str(obj_id))
    if entry is None:
        ids = ", ".join(sorted(info, key=lambda s: int(s) if s.isdigit() else 0)[:20])
        raise ValueError(f"{path}: obj_id {obj_id} is not in this dataset's models (ids: {ids})")
    return entry


def bop_object(models_dir: str | Path, obj_id: int, name: str | None = None) -> Any:
    """The opnet object model of BOP object ``obj_id``: its mesh (mm -> m, aligned so the symmetry
    axis is z) and its symmetry from models_info.json."""
    from opnet.objects.io import load_mesh
    from opnet.objects.model import ObjectModel

    models_dir = Path(models_dir)
    info = model_info(models_dir, obj_id)
    obj_id = bop_id(obj_id, "obj_id", str(models_dir / MODELS_INFO))
    symmetry, A = symmetry_from_bop(info, f"{models_dir / MODELS_INFO}: obj_id {obj_id}")
    mesh_path = models_dir / f"obj_{obj_id:06d}.ply"
    mesh = load_mesh(mesh_path, 0.001, A if np.abs(A - np.eye(3)).max() > 0 else None)
    return ObjectModel.from_mesh(name or f"obj_{obj_id:06d}", mesh, symmetry, source=str(mesh_path))


# ------------------------------------------------------------------------------------------ reader


class BOPDataset:
    """The images of a BOP split folder showing object ``obj_id``, in (scene, image) order.

    Args:
        root: the split folder, e.g. ``<dataset>/train_pbr`` (scene folders ``XXXXXX`` inside).
        obj_id: the object whose instances are the ground truth.
        clip: (near, far) metres for the depth normalization; None = from the first image's depth.
        models_dir: default ``<dataset>/models``.
    """

    def __init__(self, root: str | Path, obj_id: int, clip: tuple[float, float] | None = None,
                 models_dir: str | Path | None = None) -> None:
        self.root = Path(root)
        self.obj_id = bop_id(obj_id, "data.object_id", str(self.root))
        self.models_dir = Path(models_dir) if models_dir is not None else models_dir_of(self.root)
        info = model_info(self.models_dir, self.obj_id)
        self.symmetry, self.R_align = symmetry_from_bop(info, f"{self.models_dir / MODELS_INFO}: obj_id {obj_id}")
        self.object_name = f"obj_{self.obj_id:06d}"
        scene_dirs = sorted(p for p in self.root.iterdir() if p.is_dir() and re.fullmatch(r"\d{6}", p.name)) \
            if self.root.is_dir() else []
        if not scene_dirs:
            raise FileNotFoundError(f"{self.root}: no BOP scene folders (XXXXXX/scene_gt.json) in it")
        self._meta: dict[int, dict[str, Any]] = {}
        self._scenes: list[tuple[int, int, int]] = []
        for d in scene_dirs:
            sid = int(d.name)
            meta = {name: read_json(d / name) for name in SCENE_FILES}
            for name in SCENE_FILES:
                if not isinstance(meta[name], dict):
                    raise ValueError(f"{d / name}: expected an object of image id -> entries")
            self._meta[sid] = meta
            gt_path = d / "scene_gt.json"
            bad = [k for k in meta["scene_gt.json"] if not re.fullmatch(r"\d{1,9}", k)]
            if bad:
                raise ValueError(f"{gt_path}: image id {short_repr(bad[0])} is not a whole number")
            for key in sorted(meta["scene_gt.json"], key=int):
                where = f"{gt_path}: image {key}"
                entries = _list(meta["scene_gt.json"][key], "instances", where)
                n = sum(1 for k, e in enumerate(entries) if self._obj_id_of(e, f"{where}, instance {k}") == self.obj_id)
                self._scenes.append((sid, int(key), n))
        if not self._scenes:
            raise ValueError(f"{self.root}: no images: every scene_gt.json of its {len(scene_dirs)} scene folder(s) "
                             "is empty")
        self.clip = tuple(clip) if clip is not None else self._default_clip()

    @staticmethod
    def _obj_id_of(entry: Any, where: str) -> int:
        return bop_id(_key(entry, "obj_id", where), "obj_id", where)

    def scenes(self) -> list[tuple[int, int, int]]:
        """(scene_id, im_id, number of instances of obj_id) per image, sorted."""
        return list(self._scenes)

    def __len__(self) -> int:
        return len(self._scenes)

    def __getitem__(self, i: int) -> SceneRecord:
        sid, im, _ = self._scenes[i]
        return self.read(sid, im)

    def scene_name(self, i: int) -> str:
        sid, im, _ = self._scenes[i]
        return f"{sid:06d}_{im:06d}"

    def scene_dir(self, sid: int) -> Path:
        return self.root / f"{sid:06d}"

    def source_files(self) -> list[str]:
        """Every file the images are read from, present or not, relative to ``root``:
        ``models_info.json``, each scene's JSONs, then each image's depth PNG and the visible
        masks of its instances."""
        files = [os.path.relpath(self.models_dir / MODELS_INFO, self.root)]
        files += [f"{sid:06d}/{name}" for sid in sorted(self._meta) for name in SCENE_FILES]
        for sid, im, _ in self._scenes:
            files.append(f"{sid:06d}/depth/{im:06d}.png")
            entries = self._meta[sid]["scene_gt.json"].get(str(im))
            count = len(entries) if isinstance(entries, list) else 0
            files += [f"{sid:06d}/mask_visib/{im:06d}_{k:06d}.png" for k in range(count)]
        return files

    def _depth_mm(self, sid: int, im: int) -> tuple[np.ndarray, Path]:
        cam = self._camera_entry(sid, im)
        path = self.scene_dir(sid) / "depth" / f"{im:06d}.png"
        scale = float(_numbers(_key(cam, "depth_scale", self._where(sid, "scene_camera.json", im)), 1, "depth_scale",
                               self._where(sid, "scene_camera.json", im))[0])
        if scale <= 0:
            raise ValueError(f"{self._where(sid, 'scene_camera.json', im)}: 'depth_scale' = {scale:g}, expected > 0 "
                             "(mm per depth unit)")
        code = read_png(path, np.uint16)
        depth = code.astype(np.float64) * scale
        depth[code == 0] = np.nan
        return depth, path

    def _default_clip(self) -> tuple[float, float]:
        sid, im, _ = self._scenes[0]
        depth, path = self._depth_mm(sid, im)
        valid = depth[np.isfinite(depth)] / 1000.0
        if valid.size == 0:
            raise ValueError(f"{path}: no valid depth to derive the working range from; set data.clip")
        lo, hi = np.quantile(valid, _CLIP_QUANTILES)
        return float(max(lo * _CLIP_WIDEN[0], 1e-3)), float(hi * _CLIP_WIDEN[1])

    def _where(self, sid: int, name: str, im: int) -> str:
        return f"{self.scene_dir(sid) / name}: image {im}"

    def _camera_entry(self, sid: int, im: int) -> dict[str, Any]:
        entry = self._meta[sid]["scene_camera.json"].get(str(im))
        if not isinstance(entry, dict):
            got = "none" if entry is None else short_repr(entry)
            raise ValueError(f"{self.scene_dir(sid) / 'scene_camera.json'}: image {im} needs an entry (an object with "
                             f"cam_K, depth_scale), got {got}")
        return entry

    def camera(self, sid: int, im: int, width: int, height: int) -> Camera:
        where = self._where(sid, "scene_camera.json", im)
        K = _numbers(_key(self._camera_entry(sid, im), "cam_K", where), 9, "cam_K", where).reshape(3, 3)
        try:
            cam = Camera(K[0, 0], K[1, 1], K[0, 2], K[1, 2], width, height, *self.clip)
        except ValueError as e:
            raise ValueError(f"{where}: {e}") from None
        return cam.check_plausible(where)

    @staticmethod
    def _check_translation(t: np.ndarray, depth_range: tuple[float, float] | None, where: str) -> None:
        """A part's distance along the optical axis lies near the image's depth range (metres);
        ``cam_t_m2c`` in metres puts it a thousand times too close, in micrometres too far."""
        if depth_range is None:  # no valid depth: nothing to compare with
            return
        near, far = depth_range
        if not near * _T_RANGE_FACTORS[0] <= t[2] <= far * _T_RANGE_FACTORS[1]:
            raise ValueError(f"{where}: cam_t_m2c puts the part {t[2]:.4g} m in front of the camera, far outside the "
                             f"image's depth range [{near:.3g}, {far:.3g}] m; BOP translations are in millimetres "
                             "(metres given?)")

    def read(self, sid: int, im: int) -> SceneRecord:
        """The record of image ``im`` of scene ``sid``: depth (m), camera, the chosen object's
        instances (poses in opnet's model frame, visibility) and their visible masks."""
        depth_mm, depth_path = self._depth_mm(sid, im)
        h, w = depth_mm.shape
        valid = depth_mm[np.isfinite(depth_mm)]
        depth_range = (float(valid.min()) / 1000.0, float(valid.max()) / 1000.0) if valid.size else None
        camera = self.camera(sid, im, w, h)
        gt_path = self.scene_dir(sid) / "scene_gt.json"
        entries = _list(self._meta[sid]["scene_gt.json"].get(str(im), []), "instances", f"{gt_path}: image {im}")
        infos = self._meta[sid]["scene_gt_info.json"].get(str(im))
        if not isinstance(infos, list) or len(infos) != len(entries):
            raise ValueError(f"{self.scene_dir(sid) / 'scene_gt_info.json'}: image {im} needs one entry per "
                             f"ground-truth instance ({len(entries)} in scene_gt.json)")
        Rs, ts, vis, ids = [], [], [], []
        seg = np.zeros((h, w), np.int32)
        for k, e in enumerate(entries):
            where = f"{gt_path}: image {im}, instance {k}"
            if self._obj_id_of(e, where) != self.obj_id:
                continue
            R = _numbers(_key(e, "cam_R_m2c", where), 9, "cam_R_m2c", where).reshape(3, 3)
            t = _numbers(_key(e, "cam_t_m2c", where), 3, "cam_t_m2c", where) / 1000.0
            self._check_translation(t, depth_range, where)
            Rs.append(R @ self.R_align.T)
            ts.append(t)
            info_where = f"{self.scene_dir(sid) / 'scene_gt_info.json'}: image {im}, instance {k}"
            vis.append(float(_numbers(_key(infos[k], "visib_fract", info_where), 1, "visib_fract", info_where)[0]))
            ids.append(k + 1)
            mask_path = self.scene_dir(sid) / "mask_visib" / f"{im:06d}_{k:06d}.png"
            if mask_path.is_file():
                mask = read_png(mask_path, np.uint8)
                if mask.shape != (h, w):
                    raise ValueError(f"{mask_path}: mask is {mask.shape[1]}x{mask.shape[0]}, the depth image "
                                     f"{depth_path.name} is {w}x{h}")
                seg[mask > 0] = k + 1
        R_arr = np.array(Rs).reshape(-1, 3, 3)
        t_arr = np.array(ts).reshape(-1, 3)
        check_poses(R_arr, t_arr, lambda i: f"{gt_path}: image {im}, instance {ids[i] - 1}")
        check_range(np.array(vis), 0.0, 1.0, "visib_fract",
                    lambda i: f"{self.scene_dir(sid) / 'scene_gt_info.json'}: image {im}, instance {ids[i] - 1}")
        return SceneRecord(
            name=f"{sid:06d}_{im:06d}", depth=(depth_mm / 1000.0).astype(np.float32), camera=camera,
            segmentation=seg, R_cam_obj=R_arr, t_cam_obj=t_arr, visibility=np.array(vis, np.float64),
            instance_id=np.array(ids, np.int64), object_name=self.object_name,
        )


def is_bop_split(path: Path) -> bool:
    """A folder of BOP scene folders (``XXXXXX/scene_gt.json``)."""
    return path.is_dir() and any((p / "scene_gt.json").is_file() for p in path.iterdir() if re.fullmatch(r"\d{6}", p.name))


# ------------------------------------------------------------------------------------------ writer


def write_bop_split(records: Iterable[tuple[int, int, SceneRecord]], out: str | Path, obj_id: int = 1) -> Path:
    """Write scene records as BOP scenes under ``out`` (a split folder): depth in 0.1 mm units
    (``depth_scale`` 0.1), poses in mm, ``scene_gt_info.json`` with ``visib_fract`` (and the
    silhouette boxes / pixel counts of the visible masks), ``mask_visib`` from the segmentation.

    Args:
        records: (scene_id, im_id, record) triples; images of one scene share its folder.
    """
    out = Path(out)
    scenes: dict[int, dict[str, dict[str, Any]]] = {}
    for sid, im, rec in records:
        d = out / f"{sid:06d}"
        meta = scenes.setdefault(sid, {name: {} for name in SCENE_FILES})
        cam = rec.camera
        meta["scene_camera.json"][str(im)] = {
            "cam_K": [cam.fx, 0.0, cam.cx, 0.0, cam.fy, cam.cy, 0.0, 0.0, 1.0], "depth_scale": 0.1}
        code = np.where(np.isfinite(rec.depth), np.rint(rec.depth * 10000.0), 0)
        if code.max(initial=0) > 65535:
            raise ValueError(f"{d / 'depth' / f'{im:06d}.png'}: scene {rec.name}: depth beyond 6.5 m does not fit "
                             "BOP's 16-bit PNG at 0.1 mm")
        write_png(d / "depth" / f"{im:06d}.png", code.astype(np.uint16))
        gts, infos = [], []
        for k in range(rec.num_objects):
            gts.append({"cam_R_m2c": [float(v) for v in rec.R_cam_obj[k].reshape(-1)],
                        "cam_t_m2c": [float(v) * 1000.0 for v in rec.t_cam_obj[k]], "obj_id": int(obj_id)})
            mask = (rec.segmentation == rec.instance_id[k]) if rec.segmentation is not None else np.zeros(rec.depth.shape, bool)
            ys, xs = np.nonzero(mask)
            box = [int(xs.min()), int(ys.min()), int(xs.max() - xs.min() + 1), int(ys.max() - ys.min() + 1)] if len(xs) else [-1, -1, 0, 0]
            infos.append({"visib_fract": float(np.clip(rec.visibility[k], 0.0, 1.0)), "bbox_visib": box,
                          "px_count_visib": int(mask.sum())})
            write_png(d / "mask_visib" / f"{im:06d}_{k:06d}.png", (mask * 255).astype(np.uint8))
        meta["scene_gt.json"][str(im)] = gts
        meta["scene_gt_info.json"][str(im)] = infos
    for sid, meta in scenes.items():
        for name, doc in meta.items():
            write_text_atomic(out / f"{sid:06d}" / name, json.dumps(doc, indent=1))
    return out


def write_bop_models(models_dir: str | Path, obj: Any, obj_id: int = 1) -> Path:
    """``models_info.json`` and ``obj_XXXXXX.ply`` (mm) of an opnet object, symmetries included."""
    models_dir = Path(models_dir)
    obj_id = bop_id(obj_id, "obj_id", str(models_dir))
    if obj.mesh is None:
        raise ValueError(f"object {obj.name!r} has no mesh to write as a BOP model")
    mesh = obj.mesh.copy()
    mesh.apply_scale(1000.0)
    ply = models_dir / f"obj_{obj_id:06d}.ply"
    with disk_full_named(ply):
        models_dir.mkdir(parents=True, exist_ok=True)
        mesh.export(ply)
    lo, hi = mesh.bounds
    entry = {"diameter": float(1000.0 * obj.diameter), "min_x": float(lo[0]), "min_y": float(lo[1]),
             "min_z": float(lo[2]), "size_x": float(hi[0] - lo[0]), "size_y": float(hi[1] - lo[1]),
             "size_z": float(hi[2] - lo[2]), **bop_symmetry_entries(obj.symmetry)}
    path = models_dir / MODELS_INFO
    info = read_json(path) if path.is_file() else {}
    info[str(obj_id)] = entry
    write_text_atomic(path, json.dumps(info, indent=1))
    return models_dir


def convert_ipa_to_bop(ipa_root: str | Path, out: str | Path, split: str = "train_synt", obj_id: int = 1,
                       overwrite: bool = False) -> Path:
    """An IPA-layout dataset (e.g. from ``generate.py``) as a BOP dataset: ``<out>/models`` and
    ``<out>/<split>/<cycle as scene id>/``, each drop an image id. Returns the split folder.

    The dataset is written into a temporary folder beside ``out``, which then replaces ``out`` as a
    whole: a failed conversion leaves ``out`` as it was, a finished one leaves nothing of before.

    Raises:
        ValueError: ``out`` is a non-empty folder and not ``overwrite``; ``out`` is, holds or lies
            inside the IPA dataset.
    """
    from opnet.datasets.ipa import IPADataset
    from opnet.datasets.outputs import folder_replaced, is_within
    from opnet.objects.config import object_from_config

    out = Path(out)
    obj_id = bop_id(obj_id, "--obj-id", str(out))
    if is_within(out, ipa_root) or is_within(ipa_root, out):
        raise ValueError(f"{out}: the BOP dataset would overlap its input {ipa_root}; choose a folder outside it")
    ipa = IPADataset(ipa_root)
    object_cfg = read_json(Path(ipa_root) / "object.json")
    with folder_replaced(out, overwrite) as tmp:
        write_bop_models(tmp / "models", object_from_config(object_cfg), obj_id)
        write_bop_split(((c, n, ipa.read(c, n)) for c, n in ipa.scenes()), tmp / split, obj_id)
    return out / split


# ------------------------------------------------------------------------------------------ results


def bop_results_rows(names_hyps: Iterable[tuple[str, Any]], obj_id: int, R_align: np.ndarray | None = None,
                     seconds: float = -1.0) -> list[str]:
    """Lines of a BOP results CSV (``scene_id,im_id,obj_id,score,R,t,time``: R row-wise, t in mm)
    for scenes named ``<scene>_<image>`` (BOP) or ``cycle_XXXX_NNN`` (IPA); poses are taken back
    to the BOP model frame with ``R_align``."""
    A = np.eye(3) if R_align is None else np.asarray(R_align)
    lines = ["scene_id,im_id,obj_id,score,R,t,time"]
    for name, hyps in names_hyps:
        m = re.fullmatch(r"(?:cycle_)?(\d+)_(\d+)", name)
        if m is None:
            raise ValueError(f"scene {name!r}: not a BOP (<scene>_<image>) or IPA (cycle_XXXX_NNN) name")
        sid, im = int(m.group(1)), int(m.group(2))
        for R, t, s in zip(hyps.R, hyps.t, hyps.score):
            R_bop = np.asarray(R) @ A
            lines.append(f"{sid},{im},{int(obj_id)},{float(s):.6f},{' '.join(f'{v:.8f}' for v in R_bop.reshape(-1))},"
                         f"{' '.join(f'{1000.0 * v:.4f}' for v in t)},{seconds:g}")
    return lines



def main(argv: list[str] | None = None) -> int:
    """``python -m opnet.datasets.bop <ipa dataset> <bop dataset> [--split S] [--obj-id N] [--overwrite]``."""
    import argparse
    import sys

    from opnet.datasets.atomic import DiskFullError

    parser = argparse.ArgumentParser(prog="python -m opnet.datasets.bop",
                                     description="Write an IPA-layout dataset (e.g. from generate.py) as a BOP dataset.")
    parser.add_argument("ipa", type=Path, help="IPA-layout dataset folder (parameter.json, gt/, p_depth/, ...)")
    parser.add_argument("out", type=Path, help="BOP dataset folder to write (models/ and <split>/)")
    parser.add_argument("--split", default="train_synt", help="split folder name (default train_synt)")
    parser.add_argument("--obj-id", type=int, default=1, help="the BOP obj_id of the part (default 1)")
    parser.add_argument("--overwrite", action="store_true", help="replace a non-empty output folder (as a whole)")
    args = parser.parse_args(argv)
    try:
        split = convert_ipa_to_bop(args.ipa, args.out, args.split, args.obj_id, args.overwrite)
    except (ValueError, FileNotFoundError, DiskFullError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"BOP split written to {split} (models in {split.parent / 'models'}); train with: python train.py "
          f"data=bop object=bop data.root={split} data.object_id={args.obj_id}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
