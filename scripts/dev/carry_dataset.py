"""Pack a dataset folder small enough to carry to another machine, and unpack it there, losslessly.

    python scripts/dev/carry_dataset.py pack <dataset folder> <archive.tar.xz>
    python scripts/dev/carry_dataset.py unpack <archive.tar.xz> <folder>
    python scripts/dev/carry_dataset.py verify <dataset folder> <archive.tar.xz>
    python scripts/dev/carry_dataset.py pack-cache <dataset folder> <archive.tar.xz> --cache <cache folder name>

16-bit depth PNGs of piles compress poorly (deflate sees the bytes, not the surface): ``pack``
stores each as its row differences (uint16, wrapping), which are near zero on smooth surfaces, and
every other file as it is, in one xz-compressed tar. ``unpack`` turns the differences back into the
same pixels in a PNG (the PNG bytes may differ, the depth does not) and checks the count of files.
``verify`` unpacks the archive into a temporary folder and compares it with the dataset: the same
files, every depth image's pixels and every other file's bytes.

``pack-cache`` carries what a training reads from a dataset whose scene cache (opnet.data.cache) is
complete: the cache named (its depth shards with the two bytes of each pixel stored as two planes,
which xz packs about 8 x, against 6 x as they are; every depth pixel kept) and the dataset's other
files except its images, each kept with its modification time to the nanosecond. The images
(``*.png``, which the cache holds already) come back as empty stand-ins of their size and
modification time, what the cache's fingerprint reads, so the cache is opened as it is, but for the
first image of each top-level folder (the first scene's, which the loader's checks read: whether the
dataset has a segmentation). Train with ``data.check=off`` there (the stand-ins have no image
headers), and unpack into a folder of the dataset's own name (a reader may name the part by it, and
the fingerprint holds that name). Other caches are left behind. ``unpack`` tells the two kinds of
archive apart; ``verify`` is for ``pack``'s.
"""

from __future__ import annotations

import argparse
import io
import json
import lzma
import os
import sys
import tarfile
import tempfile
from pathlib import Path

import cv2
import numpy as np

#: a 16-bit depth image is stored as its row differences under this suffix
DIFF_SUFFIX = ".rowdiff"
MANIFEST = "carry_manifest.json"
#: a cache's depth shard is stored with its low and high bytes as two planes under this suffix
PLANES_SUFFIX = ".planes"


def _is_depth_png(path: Path) -> bool:
    return path.suffix.lower() == ".png" and "depth" in path.name.lower()


def row_differences(depth: np.ndarray) -> np.ndarray:
    """(H, W) uint16 -> (H, W) uint16: each pixel minus the one on its left (wrapping), the first column kept."""
    out = depth.copy()
    out[:, 1:] = depth[:, 1:] - depth[:, :-1]  # uint16 arithmetic wraps: exact to invert
    return out


def undo_row_differences(diff: np.ndarray) -> np.ndarray:
    """The inverse of :func:`row_differences`."""
    return np.cumsum(diff, axis=1, dtype=np.uint64).astype(np.uint16)  # sums mod 2**16


def pack(folder: Path, archive: Path) -> dict[str, int]:
    """Write ``archive`` (tar.xz) holding ``folder``; returns the counts of depth images and other files."""
    files = sorted(p for p in folder.rglob("*") if p.is_file())
    depth_count = 0
    with tarfile.open(archive, "w:xz", preset=6) as tar:
        for path in files:
            name = str(path.relative_to(folder))
            depth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED) if _is_depth_png(path) else None
            if depth is None or depth.dtype != np.uint16 or depth.ndim != 2:
                tar.add(path, arcname=name)
                continue
            diff = row_differences(depth)
            header = np.asarray(diff.shape, np.uint32).tobytes()
            _add_bytes(tar, name + DIFF_SUFFIX, header + diff.tobytes())
            depth_count += 1
        counts = {"depth_images": depth_count, "files": len(files)}
        _add_bytes(tar, MANIFEST, json.dumps(counts).encode())
    return counts


def unpack(archive: Path, folder: Path) -> dict[str, int]:
    """Restore ``archive`` into ``folder``; returns the manifest's counts.

    Raises:
        ValueError: the archive holds a path leaving ``folder``, or fewer files than it records.
    """
    folder.mkdir(parents=True, exist_ok=True)
    root = folder.resolve()
    written = 0
    counts: dict[str, int] = {}
    with tarfile.open(archive, "r:xz") as tar:
        for member in tar:
            if not member.isfile():
                continue
            target = (folder / member.name).resolve()
            if root not in target.parents:
                raise ValueError(f"{archive}: {member.name} would be written outside {folder}")
            data = tar.extractfile(member).read()
            if member.name == MANIFEST:
                counts = json.loads(data)
                continue
            target.parent.mkdir(parents=True, exist_ok=True)
            if member.name.endswith(PLANES_SUFFIX):
                target = target.with_name(target.name.removesuffix(PLANES_SUFFIX))
                target.write_bytes(_from_planes(data))
            elif member.name.endswith(DIFF_SUFFIX):
                shape = tuple(int(v) for v in np.frombuffer(data[:8], np.uint32))
                diff = np.frombuffer(data[8:], np.uint16).reshape(shape)
                target = target.with_name(target.name.removesuffix(DIFF_SUFFIX))
                if not cv2.imwrite(str(target), undo_row_differences(diff)):
                    raise ValueError(f"{target}: could not write the depth PNG")
            else:
                target.write_bytes(data)
            written += 1
    if written != counts.get("files", -1):
        raise ValueError(f"{archive}: {written} files unpacked, the manifest records {counts.get('files')}")
    for name, (size, mtime_ns) in counts.pop("stand_ins", {}).items():  # pack-cache: the images the cache holds
        target = (folder / name).resolve()
        if root not in target.parents:
            raise ValueError(f"{archive}: {name} would be written outside {folder}")
        target.parent.mkdir(parents=True, exist_ok=True)
        with target.open("wb") as f:
            f.truncate(int(size))  # sparse: no disk used
        os.utime(target, ns=(int(mtime_ns), int(mtime_ns)))
    for name, mtime_ns in counts.pop("mtimes", {}).items():
        os.utime(folder / name, ns=(int(mtime_ns), int(mtime_ns)))
    return counts


def _to_planes(data: bytes) -> bytes:
    """uint16 pixels -> their low bytes, then their high bytes (xz finds the smooth high bytes' runs)."""
    pixels = np.frombuffer(data, np.uint16)
    return (pixels & 0xFF).astype(np.uint8).tobytes() + (pixels >> 8).astype(np.uint8).tobytes()


def _from_planes(data: bytes) -> bytes:
    half = len(data) // 2
    low, high = np.frombuffer(data[:half], np.uint8), np.frombuffer(data[half:], np.uint8)
    return (low.astype(np.uint16) | high.astype(np.uint16) << 8).tobytes()


def pack_cache(folder: Path, cache: str, archive: Path) -> dict[str, int]:
    """Write ``archive`` (tar.xz) holding ``folder``'s scene cache ``cache`` and its other files but the
    images (``*.png``), which unpack as stand-ins of their size and modification time; returns the counts.

    Raises:
        ValueError: ``folder/cache`` holds no complete cache (``cache.json`` and its shards).
    """
    cache_dir = folder / cache
    if not (cache_dir / "cache.json").is_file() or not list(cache_dir.glob("shard_*.npz")):
        raise ValueError(f"{cache_dir}: no scene cache there (cache.json and its shards)")
    stored, stand_ins, mtimes, first_of = 0, {}, {}, set()
    with tarfile.open(archive, "w:xz", preset=9 | lzma.PRESET_EXTREME) as tar:
        for path in sorted(p for p in folder.rglob("*") if p.is_file()):
            name = str(path.relative_to(folder))
            top = name.split("/", 1)[0]
            if top.startswith("cache_") and top != cache:
                continue  # another cache: not what this training reads
            st = path.stat()
            if top != cache and path.suffix.lower() == ".png":
                if top in first_of:
                    stand_ins[name] = [st.st_size, st.st_mtime_ns]
                    continue
                first_of.add(top)  # the first image of its folder: carried as it is
            mtimes[name] = st.st_mtime_ns
            if top == cache and path.suffix == ".depth":
                _add_bytes(tar, name + PLANES_SUFFIX, _to_planes(path.read_bytes()))
            else:
                tar.add(path, arcname=name)
            stored += 1
        counts = {"depth_images": 0, "files": stored, "stand_ins": stand_ins, "mtimes": mtimes}
        _add_bytes(tar, MANIFEST, json.dumps(counts).encode())
    return {"files": stored, "stand_ins": len(stand_ins)}


def verify(folder: Path, archive: Path) -> dict[str, int]:
    """Unpack ``archive`` into a temporary folder and compare it with ``folder``; returns the counts.

    Raises:
        ValueError: naming the first file missing, extra, or different (depth: in its pixels).
    """
    with tempfile.TemporaryDirectory(prefix="carry_verify_") as tmp:
        out = Path(tmp)
        counts = unpack(archive, out)
        ours = sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file())
        theirs = sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.is_file())
        if ours != theirs:
            missing, extra = sorted(set(ours) - set(theirs)), sorted(set(theirs) - set(ours))
            raise ValueError(f"{archive}: files differ from {folder}: missing {missing[:3]}, extra {extra[:3]}")
        for name in ours:
            a, b = folder / name, out / name
            if _is_depth_png(a):
                da, db = cv2.imread(str(a), cv2.IMREAD_UNCHANGED), cv2.imread(str(b), cv2.IMREAD_UNCHANGED)
                if da is not None and da.dtype == np.uint16 and da.ndim == 2:
                    if db is None or db.dtype != da.dtype or not np.array_equal(da, db):
                        raise ValueError(f"{archive}: {name}: the depth differs after unpacking")
                    continue
            if a.read_bytes() != b.read_bytes():
                raise ValueError(f"{archive}: {name}: the bytes differ after unpacking")
    return counts


def _add_bytes(tar: tarfile.TarFile, name: str, data: bytes) -> None:
    info = tarfile.TarInfo(name)
    info.size = len(data)
    tar.addfile(info, io.BytesIO(data))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("action", choices=["pack", "unpack", "verify", "pack-cache"])
    ap.add_argument("source", type=Path, help="pack, verify: the dataset folder; unpack: the archive")
    ap.add_argument("target", type=Path, help="pack, verify: the archive; unpack: the folder")
    ap.add_argument("--cache", help="pack-cache: the scene cache's folder name in the dataset (cache_s...)")
    args = ap.parse_args(argv)
    try:
        if args.action == "pack":
            if not args.source.is_dir():
                raise ValueError(f"{args.source}: not a folder")
            counts = pack(args.source, args.target)
            size = args.target.stat().st_size / 2**20
            print(f"{args.target}: {counts['files']} files ({counts['depth_images']} depth images), {size:.1f} MiB")
        elif args.action == "pack-cache":
            if not args.cache:
                raise ValueError("pack-cache: --cache <the cache folder's name> is required")
            counts = pack_cache(args.source, args.cache, args.target)
            size = args.target.stat().st_size / 2**20
            print(f"{args.target}: {counts['files']} files of {args.source} with its cache {args.cache}, "
                  f"{counts['stand_ins']} images as stand-ins, {size:.1f} MiB")
        elif args.action == "unpack":
            counts = unpack(args.source, args.target)
            print(f"{args.target}: {counts['files']} files unpacked ({counts['depth_images']} depth images)")
        else:
            if not args.source.is_dir():
                raise ValueError(f"{args.source}: not a folder")
            counts = verify(args.source, args.target)
            print(f"{args.target}: the same {counts['files']} files as {args.source} "
                  f"({counts['depth_images']} depth images, pixel for pixel)")
    except (OSError, ValueError, tarfile.TarError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
