"""Check a dataset before using it: ``python -m opnet.datasets.check <root> [<root> ...] [--fast]``.

Files are otherwise read lazily, so a truncated PNG in the test split used to crash a run only
after the whole fit. This reads every file of every scene once, collects *all* problems (not only
the first), and reports each with its file name.

- full (default of the command): every scene is read with the dataset's own reader: PNGs decoded,
  ground truth validated (rotations, translations, visibilities, ids; see
  :mod:`opnet.datasets.validate`).
- fast (``--fast``; what ``train.py`` runs before fitting, ``data.check=fast``): the files exist,
  are regular and non-empty, PNG headers have the camera's size and the expected bit depth, CSVs
  start with the header. It reads a few dozen bytes per file: seconds for 10 000 scenes.
- both: a dataset made by :mod:`opnet.synthesis` (``generation.json``) must hold every scene it
  declares (``number_cycles`` of ``parameter.json`` x ``drops`` + 1 of ``generation.json``), each
  with its three files, none empty: a generation cut short by a full disk fails the check.
- both, BOP splits: the visible mask of every instance of the object in a scene with a
  ``mask_visib`` folder exists (the full check finds a missing one by reading the image); no image
  of ``scene_gt.json`` lists the same instance twice (same ``obj_id``, same pose: one part counted
  twice among those to find); every ``cam_R_w2c`` of ``scene_camera.json`` is a rotation
  (orthonormal to :data:`~opnet.datasets.validate.ORTHONORMAL_TOL`, det +1).

``--fingerprint`` prints, instead of checking, one line per dataset: a hash of every scene's name and
ground-truth poses (rounded to :data:`FINGERPRINT_DECIMALS` decimals of a metre and of a rotation entry)
and the scene count. Equal lines, the same piles; the same seed run on another CPU can settle other piles
(physics rounds its last bits otherwise and a deep pile amplifies that), which this tells at once.

Exit status: 0 no problem, 1 problems found, 2 not a dataset.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import stat
import struct
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from opnet.datasets.autodetect import open_dataset
from opnet.datasets.bop import BOPDataset
from opnet.datasets.ipa import MAX_INSTANCE_ID, IPADataset, scene_paths
from opnet.datasets.ipa_csv import CSV_HEADER, read_ipa_csv
from opnet.datasets.sileane import SileaneDataset
from opnet.datasets.sileane_json import read_gt_json
from opnet.datasets.validate import not_rotations
from opnet.fileio.files import read_json
from opnet.geometry.camera import parse_clip
from opnet.objects.bop import bop_numbers

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_GREY = 0  # IHDR colour type of a single-channel image
_PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"
#: the root file of a dataset made by opnet.synthesis (its writer's name: the synthesis package is
#: not imported here, it loads physics and rendering)
GENERATION_FILE = "generation.json"
#: scenes whose depth the fast check decodes (spread over the dataset): an all-missing depth
#: (e.g. clip planes that do not match the data) shows in any of them
DEPTH_SAMPLES = 8


@dataclass(frozen=True)
class Problem:
    path: Path
    message: str

    def __str__(self) -> str:
        return f"{self.path}: {self.message}"


@dataclass
class CheckReport:
    root: Path
    scenes: int
    problems: list[Problem]
    seconds: float

    @property
    def ok(self) -> bool:
        return not self.problems

    def summary(self, limit: int = 20) -> str:
        head = f"{self.root}: {self.scenes} scenes checked in {self.seconds:.1f} s, {len(self.problems)} problem(s)"
        lines = [head] + [f"  {p}" for p in self.problems[:limit]]
        if len(self.problems) > limit:
            lines.append(f"  ... and {len(self.problems) - limit} more (python -m opnet.datasets.check {self.root})")
        return "\n".join(lines)


def _stat_problem(path: Path) -> str | None:
    """What makes ``path`` no regular, non-empty file (from its ``stat`` alone), or None."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return "file not found"
    except OSError as e:
        return f"cannot read file ({e.strerror})"
    if not stat.S_ISREG(st.st_mode):
        return "not a regular file"
    if st.st_size == 0:
        return "empty file"
    return None


def _head(path: Path, n: int) -> bytes | str:
    """The first ``n`` bytes of a regular, non-empty file, or a problem description."""
    problem = _stat_problem(path)
    if problem is not None:
        return problem
    try:
        with open(path, "rb") as f:
            return f.read(n)
    except OSError as e:
        return f"cannot read file ({e.strerror})"


def png_header_problem(path: Path, size: tuple[int, int] | None, bits: int) -> str | None:
    """What is wrong with a PNG's header (signature, IHDR size, bit depth, channels), or None.

    Args:
        size: expected (width, height), or None to accept any.
        bits: expected bit depth (8 or 16), single channel.
    """
    head = _head(path, 33)
    if isinstance(head, str):
        return head
    if len(head) < 33 or not head.startswith(_PNG_SIGNATURE) or head[12:16] != b"IHDR":
        return "not a PNG file (bad signature or header)" if not head.startswith(_PNG_SIGNATURE) else "truncated PNG header"
    width, height, depth, colour = struct.unpack(">IIBB", head[16:26])
    if colour != _PNG_GREY:
        return f"expected a single-channel (grey) PNG, got colour type {colour}"
    if depth != bits:
        return f"expected a {bits}-bit PNG, got a {depth}-bit one"
    if size is not None and (width, height) != tuple(size):
        return f"image is {width}x{height} (WxH), expected {size[0]}x{size[1]}"
    try:  # a complete PNG ends with its IEND chunk: a cut-off copy or download does not
        with open(path, "rb") as f:
            f.seek(-12, os.SEEK_END)
            if f.read(12) != _PNG_END:
                return "truncated PNG (no IEND chunk at the end)"
    except OSError as e:
        return f"cannot read file ({e.strerror})"
    return None


def _csv_header_problem(path: Path) -> str | None:
    head = _head(path, 512)
    if isinstance(head, str):
        return head
    first = head.decode("utf-8", "replace").removeprefix("\ufeff").splitlines()[0] if head else ""
    if [c.strip() for c in first.split(",")] != CSV_HEADER:
        return f"line 1: expected the header {','.join(CSV_HEADER)}"
    return None


def _fast_ipa(ds: IPADataset) -> list[Problem]:
    problems = []
    size = (ds.camera.width, ds.camera.height)
    for cycle, n in ds.scenes():
        paths = scene_paths(ds.root, cycle, n)
        for key, problem in (("csv", _csv_header_problem(paths["csv"])),
                             ("depth", png_header_problem(paths["depth"], size, 16)),
                             ("segmentation", png_header_problem(paths["segmentation"], size, 8))):
            if problem is not None and not (key == "segmentation" and problem == "file not found"):
                problems.append(Problem(paths[key], problem))
        if not any(p.path == paths["csv"] for p in problems):
            try:  # ground truth is small: parse and validate all of it (rotations, visibilities, ids)
                read_ipa_csv(paths["csv"])
            except (ValueError, FileNotFoundError) as e:
                problems.append(_as_problem(e, paths["csv"]))
    problems += _depth_samples(ds, {p.path for p in problems})
    return problems


def _depth_samples(ds: IPADataset | SileaneDataset | BOPDataset, bad: set[Path]) -> list[Problem]:
    """Decode the depth of a few scenes spread over the dataset; a depth image without any valid
    pixel is a problem (wrong clip planes, a broken export)."""
    scenes = ds.scenes()
    if not scenes or getattr(ds, "camera", None) is None:
        return []
    picks = sorted({round(i * (len(scenes) - 1) / max(DEPTH_SAMPLES - 1, 1)) for i in range(DEPTH_SAMPLES)})
    problems = []
    for i in picks:
        scene = scenes[i]
        if isinstance(ds, BOPDataset):
            path = ds.scene_dir(scene[0]) / "depth" / f"{scene[1]:06d}.png"
        else:
            path = scene_paths(ds.root, *scene)["depth"] if isinstance(ds, IPADataset) else ds._image("depth", scene)
        if path is None or path in bad:
            continue
        try:
            record = (ds.read(*scene[:2]) if isinstance(ds, BOPDataset) else
                      ds.read(*scene) if isinstance(ds, IPADataset) else ds.read(scene))
        except (ValueError, FileNotFoundError) as e:
            if (problem := _as_problem(e, path)).path not in bad:  # a file reported already (a missing mask)
                problems.append(problem)
            continue
        if not np.isfinite(record.depth).any():
            problems.append(Problem(path, "no valid depth in the whole image (all pixels missing or outside the clip planes)"))
    return problems


def _as_problem(e: Exception, default: Path) -> Problem:
    path, _, message = str(e).partition(": ")
    return Problem(Path(path), message) if message and "/" in path else Problem(default, str(e))


def _fast_sileane(ds: SileaneDataset) -> list[Problem]:
    problems = []
    size = (ds.camera.width, ds.camera.height) if ds.camera is not None else None
    for scene in ds.scenes():
        gt = ds.root / "gt" / f"{scene}.json"
        gt = gt if gt.exists() else ds.root / "gt" / f"{scene}.JSON"
        try:  # ground truth is small: parse and validate all of it
            read_gt_json(gt)
        except (ValueError, FileNotFoundError) as e:
            problems.append(_as_problem(e, gt))
        if ds.camera is None:
            continue
        depth = ds._image("depth", scene)
        if depth is None:
            problems.append(Problem(ds.root / "depth" / f"{scene}.PNG", "file not found (also tried .png)"))
        elif (problem := png_header_problem(depth, size, 16)) is not None:
            problems.append(Problem(depth, problem))
        seg = ds._image("segmentation", scene)
        if seg is not None and (problem := png_header_problem(seg, size, 16)) is not None:
            problems.append(Problem(seg, problem))
    problems += _depth_samples(ds, {p.path for p in problems})
    return problems


def _fast_bop(ds: BOPDataset) -> list[Problem]:
    """Depth PNG headers of every image and the visible masks' headers, the masks of the object's
    instances present where the scene has a ``mask_visib`` folder (scene JSONs were parsed when the
    dataset was opened), the records of a few images read."""
    problems = []
    for sid, im, _ in ds.scenes():
        depth = ds.scene_dir(sid) / "depth" / f"{im:06d}.png"
        if (problem := png_header_problem(depth, None, 16)) is not None:
            problems.append(Problem(depth, problem))
        masks = set((ds.scene_dir(sid) / "mask_visib").glob(f"{im:06d}_*.png"))
        if ds.has_masks(sid):
            masks.update(ds.mask_path(sid, im, k) for k in ds.instances(sid, im))
        for mask in sorted(masks):
            if (problem := png_header_problem(mask, None, 8)) is not None:
                problems.append(Problem(mask, problem))
    return problems + _depth_samples(ds, {p.path for p in problems})


def _exact_instance(entry: Any) -> tuple[Any, ...] | None:
    """An instance of ``scene_gt.json`` as (obj_id, R, t) numbers to compare exactly; None for a
    malformed entry (the reader names those)."""
    try:
        return (entry["obj_id"], *(tuple(float(v) for v in entry[key]) for key in ("cam_R_m2c", "cam_t_m2c")))
    except (KeyError, TypeError, ValueError):
        return None


def _bop_annotation_problems(ds: BOPDataset) -> list[Problem]:
    """What the reader takes from the scene JSONs as it is: the same instance listed twice in one
    image of ``scene_gt.json`` (any object), a ``cam_R_w2c`` of ``scene_camera.json`` that is no
    rotation."""
    problems = []
    for sid in sorted({sid for sid, _, _ in ds.scenes()}):
        gt_path = ds.scene_dir(sid) / "scene_gt.json"
        for key, entries in ds.scene_file(sid, "scene_gt.json").items():
            seen: dict[tuple[Any, ...], int] = {}
            for k, entry in enumerate(entries if isinstance(entries, list) else []):
                if (instance := _exact_instance(entry)) is None:
                    continue
                if instance in seen:
                    problems.append(Problem(gt_path, f"image {key}: instance {k} duplicates instance {seen[instance]} "
                                                     f"(obj_id {instance[0]}, the same pose): one part listed twice"))
                else:
                    seen[instance] = k
        cam_path = ds.scene_dir(sid) / "scene_camera.json"
        for key, entry in ds.scene_file(sid, "scene_camera.json").items():
            if not isinstance(entry, dict) or "cam_R_w2c" not in entry:
                continue
            try:
                R = bop_numbers(entry["cam_R_w2c"], 9, "cam_R_w2c", f"{cam_path}: image {key}")
            except ValueError as e:
                problems.append(_as_problem(e, cam_path))
                continue
            problems += [Problem(cam_path, f"image {key}: 'cam_R_w2c' is not a rotation matrix ({why})")
                         for _, why in not_rotations(R.reshape(1, 3, 3))]
    return problems


def _generated_drops(root: Path) -> int | Problem | None:
    """``drops`` of the ``generation.json`` of a dataset made by :mod:`opnet.synthesis`; None for
    other datasets, a problem naming the file and key when it is unreadable."""
    path = root / GENERATION_FILE
    if not path.exists():
        return None
    try:
        doc = read_json(path)
    except (ValueError, FileNotFoundError) as e:
        return _as_problem(e, path)
    drops = doc.get("drops") if isinstance(doc, dict) else None
    if isinstance(drops, bool) or not isinstance(drops, int) or not 0 <= drops <= MAX_INSTANCE_ID:
        return Problem(path, f"'drops' must be an integer in 0..{MAX_INSTANCE_ID} (parts dropped per cycle)")
    return drops


def _generation_problems(ds: IPADataset, reported: set[Path]) -> list[Problem]:
    """A generated dataset holds every scene it declares: cycles 0 .. ``number_cycles`` - 1 of
    ``parameter.json``, each with scenes 000 .. ``drops`` of ``generation.json``, each scene with
    its CSV, depth and segmentation PNGs, none empty. A generation cut short (a full disk, a
    killed run) misses some; only the scenes present would be checked otherwise. Files in
    ``reported`` already have a problem."""
    drops = _generated_drops(ds.root)
    if not isinstance(drops, int):
        return [drops] if drops is not None else []
    declared = (f"incomplete generation: parameter.json number_cycles={ds.params.number_cycles}, "
                f"generation.json drops={drops} (scenes 000..{drops:03d} per cycle)")
    cycles_present = {c for c, _ in ds.scenes()}
    problems = []
    for cycle in range(ds.params.number_cycles):
        if cycle not in cycles_present:
            folder = ds.root / "gt" / f"cycle_{cycle:04d}"
            problems.append(Problem(folder, f"cycle missing ({declared})"))
            continue
        for n in range(drops + 1):
            for path in scene_paths(ds.root, cycle, n).values():
                problem = None if path in reported else _stat_problem(path)
                if problem is not None:
                    problems.append(Problem(path, f"{problem} ({declared})"))
    return problems


def _full(ds: IPADataset | SileaneDataset | BOPDataset) -> list[Problem]:
    problems = []
    for scene in ds.scenes():
        try:
            if isinstance(ds, BOPDataset):
                record, depth_path = ds.read(*scene[:2]), ds.scene_dir(scene[0]) / "depth" / f"{scene[1]:06d}.png"
            elif isinstance(ds, IPADataset):
                record, depth_path = ds.read(*scene), scene_paths(ds.root, *scene)["depth"]
            elif ds.camera is not None:
                record, depth_path = ds.read(scene), ds._image("depth", scene)
            else:  # ground truth only (like the official evaluation sample)
                ds.read_ground_truth(scene)
                continue
        except (ValueError, FileNotFoundError) as e:
            problems.append(_as_problem(e, ds.root))
            continue
        if not np.isfinite(record.depth).any():
            problems.append(Problem(depth_path, "no valid depth in the whole image (all pixels missing or outside the clip planes)"))
    return problems


def check_dataset(root: str | Path, fast: bool = False, object_id: int | None = None,
                  clip: tuple[float, float] | None = None) -> CheckReport:
    """Check every scene of the dataset in ``root``; problems are collected, not raised.

    Raises:
        FileNotFoundError / ValueError: ``root`` is not a readable dataset at all (no
            ``parameter.json`` / ``camera_params.txt``, or a malformed one).
    """
    start = time.perf_counter()
    ds = open_dataset(root, object_id=object_id, clip=clip)
    if isinstance(ds, BOPDataset):
        problems = (_fast_bop(ds) if fast else _full(ds)) + _bop_annotation_problems(ds)
    elif fast:
        problems = _fast_ipa(ds) if isinstance(ds, IPADataset) else _fast_sileane(ds)
    else:
        problems = _full(ds)
    if isinstance(ds, IPADataset):
        problems += _generation_problems(ds, {p.path for p in problems})
    return CheckReport(Path(root), len(ds), problems, time.perf_counter() - start)


#: decimals the poses are rounded to before :func:`pile_fingerprint` hashes them (1 µm, 1e-6 of a rotation
#: entry): the same piles written with more digits hash alike, piles a physics engine settled otherwise do not
FINGERPRINT_DECIMALS = 6


def _poses(ds: IPADataset | SileaneDataset | BOPDataset, scene: Any) -> np.ndarray:
    """(N, 12) rotation entries and translations (metres) of the ground truth of ``scene``."""
    if isinstance(ds, BOPDataset):
        record = ds.read(*scene[:2])
        R, t = record.R_cam_obj, record.t_cam_obj
    else:
        gt = ds.read_ground_truth(*scene) if isinstance(ds, IPADataset) else ds.read_ground_truth(scene)
        R, t = gt.R, gt.t
    return np.concatenate([np.reshape(R, (-1, 9)), np.reshape(t, (-1, 3))], axis=1)


def pile_fingerprint(root: str | Path, object_id: int | None = None,
                     clip: tuple[float, float] | None = None) -> tuple[str, int]:
    """A 16-hex-digit hash of the dataset in ``root`` (its scenes' names and ground-truth poses in their
    order, rounded to :data:`FINGERPRINT_DECIMALS`) and its scene count.

    Raises:
        FileNotFoundError / ValueError: ``root`` is not a readable dataset, or a scene's ground truth is
            unreadable (the message names its file).
    """
    ds = open_dataset(root, object_id=object_id, clip=clip)
    digest = hashlib.sha256()
    scenes = ds.scenes()
    for scene in scenes:
        poses = np.round(_poses(ds, scene), FINGERPRINT_DECIMALS) + 0.0  # + 0.0: -0.0 hashes as 0.0
        digest.update(repr(scene).encode() + poses.astype("<f8").tobytes())
    return digest.hexdigest()[:16], len(scenes)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m opnet.datasets.check", description=__doc__.split("\n\n")[0])
    parser.add_argument("roots", nargs="+", type=Path, help="dataset folders (IPA or Siléane layout)")
    parser.add_argument("--fast", action="store_true", help="headers and sizes only (what train.py runs)")
    parser.add_argument("--limit", type=int, default=50, help="problems listed per dataset")
    parser.add_argument("--object-id", type=int, help="BOP splits: the obj_id to check")
    parser.add_argument("--clip", type=float, nargs=2, metavar=("NEAR", "FAR"), help="BOP splits: working range, metres")
    parser.add_argument("--fingerprint", action="store_true",
                        help="print a hash of each dataset's ground-truth poses instead of checking it")
    args = parser.parse_args(argv)
    try:  # the user's planes, not every image's camera, are wrong: one line, before any scene is read
        clip = parse_clip(args.clip, "--clip")
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    status = 0
    for root in args.roots:
        try:
            if args.fingerprint:
                print("{}  {} scenes  {}".format(*pile_fingerprint(root, args.object_id, clip), root))
                continue
            report = check_dataset(root, fast=args.fast, object_id=args.object_id, clip=clip)
        except (ValueError, FileNotFoundError) as e:
            print(f"error: {e}", file=sys.stderr)
            status = 2
            continue
        print(report.summary(args.limit))
        status = max(status, 0 if report.ok else 1)
    return status


if __name__ == "__main__":
    sys.exit(main())
