"""A dataset's scenes at network scale, in flat binary shards read with ``pread`` (bounded memory).

Reading an IPA or Siléane scene means decoding two PNGs and a CSV at the capture resolution, and
keeping the decoded records in memory made a training process grow with the dataset (6,600 scenes
at 256² took 3.8 GB). The cache stores each scene once, already cropped to the square canvas of
:func:`opnet.data.preprocess.square_canvas` and resized (NaN-aware ``INTER_AREA``) to ``size``
pixels, by default twice the network input, so the random resize interpolation of the sim-to-real
recipe (docs/method.md#network-input) still has pixels to interpolate:

``<root>/cache_s<size>/``
    ``cache.json``          version, size, scene count, the source's scene keys, and a fingerprint
                            of them and of every source file's size and mtime (a change rebuilds)
    ``shard_NNNNN.depth``   raw uint16 (n, size, size): ``z = clip_start + code (clip_end -
                            clip_start) / 65534``, 65535 = missing depth
    ``shard_NNNNN.seg``     raw uint8 or uint16 (n, size, size) instance ids, nearest resize
    ``shard_NNNNN.npz``     cameras (n, 8), ground truth (flat, with per-scene counts), names;
                            written last: a shard is complete when its ``.npz`` exists

An image that does not fill its square canvas (not square, or an off-centre principal point, as
Siléane's) keeps the padding as missing depth, which the network input's fill then interpolates
(reading the files directly replicates the image border there instead).

Readers fetch one scene's pixels with ``os.pread`` (no memory map, so nothing accumulates in the
process's resident memory over an epoch; DataLoader workers share nothing but the page cache) and
keep only the small ground-truth arrays. Building is resumable (complete shards are kept) and
deterministic; files are written atomically.
"""

from __future__ import annotations

import hashlib
import io
import json
import logging
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from opnet.data.preprocess import (
    _depth_canvas,
    _resize_weighted,
    network_camera,
    resize_segmentation,
    square_canvas,
)
from opnet.datasets.record import SceneRecord
from opnet.fileio.atomic import write_bytes_atomic, write_text_if_changed
from opnet.geometry.camera import Camera
from opnet.paths import user_cache_dir

log = logging.getLogger(__name__)

CACHE_VERSION = 1
MISSING = 65535
_CODE_MAX = 65534


def scene_keys(source: Any) -> list[Any]:
    """The source's scene keys: (cycle, objects) for IPA layouts, scene names otherwise."""
    if hasattr(source, "scenes"):
        return [tuple(k) if isinstance(k, (tuple, list)) else k for k in source.scenes()]
    return list(range(len(source)))


#: reader settings that change the records of the same files (stored object name, BOP object and clip)
_SOURCE_SETTINGS = ("object_name", "obj_id", "clip")


def source_fingerprint(source: Any, keys: Sequence[Any]) -> str:
    """What the cached content depends on: the scene keys, the reader's settings, and the path,
    size and modification time (ns) of every file the scenes are read from
    (``source.source_files()``, relative to ``source.root``; a missing file counts too).

    Only ``stat`` calls, no file is opened: 0.25 s per 10,000 IPA scenes on a busy 2-core machine
    (``scripts/bench/bench_cache_fingerprint.py``). A copy that does not keep modification times
    (``cp`` without ``-p``) rebuilds the cache once.
    """
    digest = hashlib.sha256(json.dumps([list(k) if isinstance(k, tuple) else k for k in keys]).encode())
    digest.update(repr([getattr(source, name, None) for name in _SOURCE_SETTINGS]).encode())
    root = str(getattr(source, "root", ""))
    lines = []
    for name in source.source_files() if hasattr(source, "source_files") else []:
        try:
            st = os.stat(os.path.join(root, name))
            lines.append(f"{name}\t{st.st_size}\t{st.st_mtime_ns}\n")
        except OSError:
            lines.append(f"{name}\t-\n")
    digest.update("".join(lines).encode())
    return digest.hexdigest()[:16]


def encode_depth(depth: np.ndarray, camera: Camera) -> np.ndarray:
    """(H, W) float metres (NaN = missing) -> uint16 codes between the clip planes."""
    z = (depth - camera.clip_start) / (camera.clip_end - camera.clip_start)
    code = np.rint(np.clip(np.nan_to_num(z, nan=0.0), 0.0, 1.0) * _CODE_MAX).astype(np.uint16)
    code[~np.isfinite(depth) | (depth <= 0)] = MISSING
    return code


def decode_depth(code: np.ndarray, camera: Camera) -> np.ndarray:
    """Inverse of :func:`encode_depth`: float32 metres, NaN where missing."""
    scale = np.float32((camera.clip_end - camera.clip_start) / _CODE_MAX)
    depth = np.float32(camera.clip_start) + code.astype(np.float32) * scale
    depth[code == MISSING] = np.nan
    return depth


def canvas_record(record: SceneRecord, size: int, fit: str = "pad") -> SceneRecord:
    """The record on its square canvas (framing ``fit``) resized to ``size`` (what the cache
    stores, before coding)."""
    x0, y0, side = square_canvas(record.camera, fit)
    values, weight = _depth_canvas(record.depth, x0, y0, side)
    depth = _resize_weighted(values, weight, size, cv2.INTER_AREA)
    camera = network_camera(record.camera, size, fit)
    seg = None
    if record.segmentation is not None:
        seg = resize_segmentation(record.segmentation, record.camera, size, fit=fit)
    return SceneRecord(
        record.name, depth, camera, seg, record.R_cam_obj, record.t_cam_obj, record.visibility,
        record.instance_id, record.object_name,
    )  # fmt: skip


@dataclass(frozen=True)
class CacheInfo:
    """The ``cache.json`` of a cache folder."""

    size: int
    num_scenes: int
    shard_scenes: int
    fingerprint: str
    keys: list[Any]
    fit: str = "pad"

    def settings(self) -> tuple[Any, ...]:
        """What must match for the cached shards to be reused."""
        return self.size, self.num_scenes, self.shard_scenes, self.fingerprint, self.fit

    @property
    def num_shards(self) -> int:
        return -(-self.num_scenes // self.shard_scenes)

    def to_json(self) -> str:
        keys = [list(k) if isinstance(k, tuple) else k for k in self.keys]
        return json.dumps({"version": CACHE_VERSION, "size": self.size, "num_scenes": self.num_scenes,
                           "shard_scenes": self.shard_scenes, "fingerprint": self.fingerprint,
                           "keys": keys, **({"fit": self.fit} if self.fit != "pad" else {})})  # fmt: skip

    @classmethod
    def read(cls, path: Path) -> CacheInfo | None:
        """The info of a cache folder, None if absent, unreadable or of another version."""
        try:
            raw = json.loads((path / "cache.json").read_text())
            if raw.get("version") != CACHE_VERSION:
                return None
            keys = [tuple(k) if isinstance(k, list) else k for k in raw["keys"]]
            return cls(int(raw["size"]), int(raw["num_scenes"]), int(raw["shard_scenes"]), str(raw["fingerprint"]), keys,
                       str(raw.get("fit", "pad")))
        except (OSError, ValueError, KeyError, TypeError):
            return None


def default_cache_dir(root: str | Path, size: int, fit: str = "pad", roi: str = "") -> Path:
    """``<root>/cache_s<size>`` (``_<fit>`` appended for another framing than ``pad``, ``roi`` (a
    :func:`opnet.data.roi.roi_tag`) for cropped scenes; also for a dataset still to be generated);
    for a dataset on read-only storage without a complete cache there, a folder of the user cache
    ($OPNET_CACHE or ~/.cache/opnet) named by the dataset."""
    tag = (f"s{size}" if fit == "pad" else f"s{size}_{fit}") + roi
    local = Path(root) / f"cache_{tag}"
    if not Path(root).exists() or os.access(root, os.W_OK) or (local / "cache.json").is_file() and not _incomplete(local):
        return local
    digest = hashlib.sha1(str(Path(root).resolve()).encode()).hexdigest()[:16]
    return user_cache_dir() / "scenes" / f"{Path(root).name}_{digest}_{tag}"


def _incomplete(path: Path) -> bool:
    info = CacheInfo.read(path)
    return info is None or any(not _shard_stem(path, s).with_suffix(".npz").is_file() for s in range(info.num_shards))


def _discard(path: Path) -> None:
    """Delete a cache folder's files (``cache.json`` first: a build killed half-way leaves shards
    without it, which the next build discards too), keeping anything else in the folder."""
    if not path.is_dir():
        return
    try:
        (path / "cache.json").unlink(missing_ok=True)
        for f in [*path.glob("shard_*"), *path.glob(".shard_*.tmp"), *path.glob(".cache.json.*.tmp")]:
            f.unlink(missing_ok=True)
    except OSError as e:
        raise ValueError(f"{path}: the scene cache is stale (its dataset or settings changed) and cannot be "
                         f"rebuilt there ({e.strerror}); delete it, or set data.cache_dir to a writable folder") from None


ORPHAN_AGE_S = 600.0  # a shard's temporary file lives seconds; one this old was left by a killed build


def _sweep_orphans(path: Path, now: float | None = None) -> int:
    """Delete the temporary files that a build killed mid-write left behind (older than
    :data:`ORPHAN_AGE_S`, so another process's write in progress is never touched); returns their number."""
    now = time.time() if now is None else now
    swept = 0
    for f in [*path.glob(".shard_*.tmp"), *path.glob(".cache.json.*.tmp")]:
        try:
            if now - f.stat().st_mtime > ORPHAN_AGE_S:
                f.unlink()
                swept += 1
        except OSError:  # gone meanwhile, or read-only storage: harmless either way
            continue
    return swept


def _shard_stem(path: Path, shard: int) -> Path:
    return path / f"shard_{shard:05d}"


def _write_shard(source: Any, path: Path, shard: int, info: CacheInfo) -> None:
    start = shard * info.shard_scenes
    indices = range(start, min(start + info.shard_scenes, info.num_scenes))
    depth = np.empty((len(indices), info.size, info.size), np.uint16)
    segs: list[np.ndarray] = []
    cams, counts, names = [], [], []
    R, t, vis, ids = [], [], [], []
    for k, i in enumerate(indices):
        rec = canvas_record(source[i], info.size, info.fit)
        depth[k] = encode_depth(rec.depth, rec.camera)
        segs.append(np.zeros((info.size, info.size), np.int64) if rec.segmentation is None else rec.segmentation)
        cams.append(rec.camera.row())
        counts.append(rec.num_objects)
        names.append(rec.name)
        R.append(rec.R_cam_obj.reshape(-1, 9))
        t.append(rec.t_cam_obj.reshape(-1, 3))
        vis.append(rec.visibility)
        ids.append(rec.instance_id)
    seg = np.stack(segs)
    if seg.min() < 0 or seg.max() > np.iinfo(np.uint16).max:
        raise ValueError(f"{path}: instance ids outside [0, 65535] cannot be cached")
    seg = seg.astype(np.uint8 if seg.max() <= 255 else np.uint16)
    stem = _shard_stem(path, shard)
    write_bytes_atomic(stem.with_suffix(".depth"), depth.tobytes())
    write_bytes_atomic(stem.with_suffix(".seg"), seg.tobytes())
    buf = io.BytesIO()
    np.savez(
        buf, cameras=np.asarray(cams, np.float64), counts=np.asarray(counts, np.int64),
        R=np.concatenate(R).astype(np.float64), t=np.concatenate(t).astype(np.float64),
        visibility=np.concatenate(vis).astype(np.float64), instance_id=np.concatenate(ids).astype(np.int64),
        names=np.asarray(names), object_names=np.asarray([source[indices[0]].object_name] if len(indices) else [""]),
        seg_dtype=np.asarray(seg.dtype.str),
    )  # fmt: skip
    write_bytes_atomic(stem.with_suffix(".npz"), buf.getvalue())


def _build_shards(args: tuple[Any, Path, list[int], CacheInfo]) -> int:
    source, path, shards, info = args
    for shard in shards:
        _write_shard(source, path, shard, info)
    return len(shards)


def build_scene_cache(
    source: Any, path: str | Path, size: int = 256, shard_scenes: int = 512, workers: int = 1, fit: str = "pad"
) -> SceneCache:
    """Write (or complete) the cache of a dataset and open it.

    Args:
        source: a dataset (``__len__``, ``__getitem__`` -> :class:`SceneRecord`, ``scenes()``).
        path: the cache folder (created).
        size: side of the cached square canvas in pixels.
        shard_scenes: scenes per shard file.
        workers: processes that build shards in parallel (the source must be picklable).
        fit: the framing of the canvas (:func:`opnet.data.preprocess.square_canvas`).
    Returns:
        The opened cache. A folder holding a cache of other settings, of another scene list or of
        source files that changed since (:func:`source_fingerprint`) is rebuilt from scratch.
    Raises:
        ValueError: a stale cache in a folder where it cannot be deleted (read-only storage).
    """
    path = Path(path)
    if size < 1 or shard_scenes < 1:
        raise ValueError(f"scene cache: size={size} and shard_scenes={shard_scenes} must be positive")
    keys = scene_keys(source)
    info = CacheInfo(int(size), len(keys), int(shard_scenes), source_fingerprint(source, keys), keys, fit)
    old = CacheInfo.read(path)
    if old is None or old.settings() != info.settings():
        if old is not None:
            log.warning("%s: cache of other settings, scenes or dataset files; rebuilding", path)
        _discard(path)
    path.mkdir(parents=True, exist_ok=True)
    if _sweep_orphans(path):
        log.info("%s: removed the temporary files of a build that was killed", path)
    write_text_if_changed(path / "cache.json", info.to_json())  # a complete cache is opened without writes
    todo = [s for s in range(info.num_shards) if not _shard_stem(path, s).with_suffix(".npz").is_file()]
    if todo:
        log.info("%s: caching %d scenes at %d px (%d shards)", path, info.num_scenes, size, len(todo))
        workers = max(1, min(int(workers), len(todo)))
        if workers == 1:
            _build_shards((source, path, todo, info))
        else:
            from opnet._pool import spawn_imap_unordered

            jobs = [(source, path, todo[w::workers], info) for w in range(workers)]
            for _ in spawn_imap_unordered(_build_shards, jobs, workers):
                pass
    return SceneCache(path)


class SceneCache:
    """Read-only access to a cache folder written by :func:`build_scene_cache`.

    Behaves like the source dataset: ``len``, ``cache[i]`` -> :class:`SceneRecord` (at the cached
    resolution, on the square canvas), ``scenes()`` (the source's keys), ``scene_name(i)``.
    Safe to use from several processes (files are opened per process, on first use).
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        info = CacheInfo.read(self.path)
        if info is None:
            raise FileNotFoundError(f"{self.path}: no scene cache (cache.json missing or of another version)")
        self.info = info
        missing = [s for s in range(info.num_shards) if not _shard_stem(self.path, s).with_suffix(".npz").is_file()]
        if missing:
            raise FileNotFoundError(f"{self.path}: scene cache incomplete, shards {missing[:5]} missing")
        self._gt: dict[int, dict[str, np.ndarray]] = {}
        self._files: dict[tuple[int, str], int] = {}
        self._pid = os.getpid()

    def __len__(self) -> int:
        return self.info.num_scenes

    def scenes(self) -> list[Any]:
        return list(self.info.keys)

    def scene_name(self, i: int) -> str:
        shard, k = divmod(i, self.info.shard_scenes)
        return str(self._shard_gt(shard)["names"][k])

    def _shard_gt(self, shard: int) -> dict[str, np.ndarray]:
        if shard not in self._gt:
            path = _shard_stem(self.path, shard).with_suffix(".npz")
            try:
                with np.load(path) as z:
                    gt = {k: z[k] for k in z.files}
            except (OSError, ValueError) as e:
                raise ValueError(f"{path}: unreadable scene-cache shard ({e}); delete the cache folder") from e
            gt["offsets"] = np.concatenate(([0], np.cumsum(gt["counts"])))
            self._gt[shard] = gt
        return self._gt[shard]

    def _read(self, shard: int, kind: str, k: int, dtype: np.dtype) -> np.ndarray:
        if self._pid != os.getpid():  # forked into a DataLoader worker: open our own files
            self._files, self._pid = {}, os.getpid()
        key = (shard, kind)
        if key not in self._files:
            self._files[key] = os.open(_shard_stem(self.path, shard).with_suffix(f".{kind}"), os.O_RDONLY)
        n = self.info.size * self.info.size
        data = os.pread(self._files[key], n * dtype.itemsize, k * n * dtype.itemsize)
        if len(data) != n * dtype.itemsize:
            raise ValueError(f"{self.path}: shard {shard} .{kind} is truncated; delete the cache folder")
        return np.frombuffer(data, dtype=dtype).reshape(self.info.size, self.info.size)

    def __getitem__(self, i: int) -> SceneRecord:
        if not 0 <= i < len(self):
            raise IndexError(f"scene {i} outside the cache's {len(self)} scenes")
        shard, k = divmod(i, self.info.shard_scenes)
        gt = self._shard_gt(shard)
        camera = Camera.from_row(gt["cameras"][k])
        depth = decode_depth(self._read(shard, "depth", k, np.dtype(np.uint16)), camera)
        seg = self._read(shard, "seg", k, np.dtype(str(gt["seg_dtype"]))).astype(np.int32)
        a, b = gt["offsets"][k], gt["offsets"][k + 1]
        return SceneRecord(
            str(gt["names"][k]), depth, camera, seg, gt["R"][a:b].reshape(-1, 3, 3), gt["t"][a:b],
            gt["visibility"][a:b], gt["instance_id"][a:b], str(gt["object_names"][0]),
        )  # fmt: skip

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state["_files"] = {}
        return state

    def __del__(self) -> None:
        for fd in getattr(self, "_files", {}).values():
            try:
                os.close(fd)
            except OSError:
                pass


__all__ = ["SceneCache", "build_scene_cache", "canvas_record", "decode_depth", "default_cache_dir", "encode_depth",
           "source_fingerprint"]
