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
        mask_visib/XXXXXX_YYYYYY.png      visible silhouette of GT instance YYYYYY (optional, see below)

One object id per model, as the paper trains one network per object: instances of the chosen
``obj_id`` are the ground truth, other objects are clutter (background in the segmentation).
Poses go to opnet's model frame, which puts a symmetry axis on z (``R_align``, see
:func:`symmetry_from_bop`); every reader error names the file.

Visible masks: the BOP format makes the ``mask_visib`` folder optional, so a scene folder without
one is read without segmentation (``SceneRecord.segmentation`` None; every instance kept with its
``visib_fract``; opening the split logs how many scenes lack it). A scene folder *with* one must hold
the mask of every instance of the chosen object: a missing file is an error naming it, never an
instance dropped (with an empty silhouette, cropping to a region of interest would zero its
visibility and take it out of the parts to find).
"""

from __future__ import annotations

import json
import logging
import os
import re
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from opnet._repr import short_repr
from opnet.datasets.png import read_png, write_png
from opnet.datasets.record import SceneRecord
from opnet.datasets.validate import check_poses, check_range
from opnet.fileio.atomic import disk_full_named, write_text_atomic
from opnet.fileio.files import read_json
from opnet.geometry.camera import Camera
from opnet.objects.bop import (
    MODELS_INFO,
    bop_id,
    bop_key,
    bop_list,
    bop_numbers,
    bop_symmetry_entries,
    model_info,
    models_dir_of,
    symmetry_from_bop,
)

log = logging.getLogger(__name__)

SCENE_FILES = ("scene_camera.json", "scene_gt.json", "scene_gt_info.json")
#: a ground-truth translation must lie within these factors of the image's depth range (nearest,
#: farthest valid pixel): ``cam_t_m2c`` in metres instead of millimetres puts every part a thousand
#: times too close
_T_RANGE_FACTORS = (0.5, 2.0)
#: default working range of BOP data without clip planes: these quantiles of the valid depth of
#: the first image, widened by the factors below
_CLIP_QUANTILES, _CLIP_WIDEN = (0.01, 0.99), (0.8, 1.25)


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
                self._scenes.append((sid, int(key), len(self.instances(sid, int(key)))))
        if not self._scenes:
            raise ValueError(f"{self.root}: no images: every scene_gt.json of its {len(scene_dirs)} scene folder(s) "
                             "is empty")
        unmasked = [sid for sid in self._meta if not self.has_masks(sid)]
        if unmasked:
            log.warning("%s: %d of %d scene folder(s) have no mask_visib folder (optional in BOP; first %06d): their "
                        "images are read without segmentation, visibilities from scene_gt_info.json", self.root,
                        len(unmasked), len(self._meta), unmasked[0])
        self.clip = tuple(clip) if clip is not None else self._default_clip()

    @staticmethod
    def _obj_id_of(entry: Any, where: str) -> int:
        return bop_id(bop_key(entry, "obj_id", where), "obj_id", where)

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

    def scene_file(self, sid: int, name: str) -> dict[str, Any]:
        """The parsed scene JSON ``name`` (one of :data:`SCENE_FILES`) of scene ``sid``."""
        return self._meta[sid][name]

    def has_masks(self, sid: int) -> bool:
        """Scene ``sid`` has a ``mask_visib`` folder (then every instance of the object needs its mask)."""
        return (self.scene_dir(sid) / "mask_visib").is_dir()

    def mask_path(self, sid: int, im: int, k: int) -> Path:
        """The visible mask of instance ``k`` (its index in ``scene_gt.json``) of image ``im``."""
        return self.scene_dir(sid) / "mask_visib" / f"{im:06d}_{k:06d}.png"

    def instances(self, sid: int, im: int) -> list[int]:
        """The indices in ``scene_gt.json`` of the instances of ``obj_id`` in image ``im``."""
        where = f"{self.scene_dir(sid) / 'scene_gt.json'}: image {im}"
        entries = bop_list(self._meta[sid]["scene_gt.json"].get(str(im), []), "instances", where)
        return [k for k, e in enumerate(entries) if self._obj_id_of(e, f"{where}, instance {k}") == self.obj_id]

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
        scale = float(bop_numbers(bop_key(cam, "depth_scale", self._where(sid, "scene_camera.json", im)), 1, "depth_scale",
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
        K = bop_numbers(bop_key(self._camera_entry(sid, im), "cam_K", where), 9, "cam_K", where).reshape(3, 3)
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
        instances (poses in opnet's model frame, visibility) and their visible masks (None for a
        scene without a ``mask_visib`` folder).

        Raises:
            FileNotFoundError: the depth PNG, or the mask of an instance of the object in a scene
                with a ``mask_visib`` folder, is missing (the message names the file).
            ValueError: a malformed entry or file, naming it.
        """
        depth_mm, depth_path = self._depth_mm(sid, im)
        h, w = depth_mm.shape
        valid = depth_mm[np.isfinite(depth_mm)]
        depth_range = (float(valid.min()) / 1000.0, float(valid.max()) / 1000.0) if valid.size else None
        camera = self.camera(sid, im, w, h)
        gt_path = self.scene_dir(sid) / "scene_gt.json"
        entries = bop_list(self._meta[sid]["scene_gt.json"].get(str(im), []), "instances", f"{gt_path}: image {im}")
        infos = self._meta[sid]["scene_gt_info.json"].get(str(im))
        if not isinstance(infos, list) or len(infos) != len(entries):
            raise ValueError(f"{self.scene_dir(sid) / 'scene_gt_info.json'}: image {im} needs one entry per "
                             f"ground-truth instance ({len(entries)} in scene_gt.json)")
        Rs, ts, vis, ids = [], [], [], []
        seg = np.zeros((h, w), np.int32) if self.has_masks(sid) else None
        for k in self.instances(sid, im):
            e, where = entries[k], f"{gt_path}: image {im}, instance {k}"
            R = bop_numbers(bop_key(e, "cam_R_m2c", where), 9, "cam_R_m2c", where).reshape(3, 3)
            t = bop_numbers(bop_key(e, "cam_t_m2c", where), 3, "cam_t_m2c", where) / 1000.0
            self._check_translation(t, depth_range, where)
            Rs.append(R @ self.R_align.T)
            ts.append(t)
            info_where = f"{self.scene_dir(sid) / 'scene_gt_info.json'}: image {im}, instance {k}"
            vis.append(float(bop_numbers(bop_key(infos[k], "visib_fract", info_where), 1, "visib_fract", info_where)[0]))
            ids.append(k + 1)
            if seg is None:  # no mask_visib folder: BOP's optional masks (module docstring)
                continue
            mask_path = self.mask_path(sid, im, k)
            if not mask_path.is_file():
                raise FileNotFoundError(f"{mask_path}: file not found: the visible mask of instance {k} of image {im} "
                                        "in scene_gt.json (the scene's mask_visib folder needs one per instance)")
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

    from opnet.fileio.atomic import DiskFullError

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
