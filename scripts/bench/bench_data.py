"""Memory and speed of the training data path at scale: one epoch of the training DataLoader
(records -> crop/resize -> augmentation -> collate), peak resident memory and images/s.

    python scripts/bench/bench_data.py --data <IPA dataset> [--scenes 5000 50000] [--workers 0 2]
    python scripts/bench/bench_data.py --data <dir> --no-cache        # read the PNG/CSV files instead
    python scripts/bench/bench_data.py --data <dir> --no-cache --memoize   # ... and keep every record
                                                                     # (what opnet did before)

``--scenes N`` larger than the dataset repeats its scenes (under new cycle numbers) to reach N:
the cache is then built from N records, as a dataset of N scenes would be, which is what the
memory and speed figures depend on (not on the scenes' content). Peak memory is the process's
resident set (VmHWM) plus that of its DataLoader workers, sampled every 0.5 s; the page cache of
the shard files is the kernel's and not counted. Each row runs in a fresh process.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

from opnet.fileio.atomic import append_csv_rows  # noqa: E402


class Memoized:
    """Keeps every record read, as the DataModule did before the scene cache (the baseline)."""

    def __init__(self, source: Any) -> None:
        self.source, self.records = source, {}

    def scenes(self) -> list[Any]:
        return self.source.scenes()

    def __len__(self) -> int:
        return len(self.source)

    def __getitem__(self, i: int) -> Any:
        if i not in self.records:
            self.records[i] = self.source[i]
        return self.records[i]


class Repeated:
    """A dataset's scenes repeated ``n // len`` times (keys: cycle + k * cycle_span)."""

    def __init__(self, source: Any, n: int) -> None:
        self.source, self.n = source, n
        keys = source.scenes()
        span = max(k[0] for k in keys) + 1
        self.keys = [(keys[i % len(keys)][0] + (i // len(keys)) * span, keys[i % len(keys)][1]) for i in range(n)]

    def scenes(self) -> list[Any]:
        return list(self.keys)

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, i: int) -> Any:
        record = self.source[i % len(self.source)]
        record.name = f"cycle_{self.keys[i][0]:04d}_{self.keys[i][1]:03d}"
        return record


def rss_mb(pids: list[int]) -> float:
    total = 0.0
    for pid in pids:
        try:
            for line in Path(f"/proc/{pid}/status").read_text().splitlines():
                if line.startswith("VmRSS:"):
                    total += int(line.split()[1]) / 1024
        except OSError:
            pass
    return total


def child_pids(pid: int) -> list[int]:
    try:
        out = subprocess.run(["pgrep", "-P", str(pid)], capture_output=True, text=True).stdout
        return [int(p) for p in out.split()]
    except OSError:
        return []


def run_one(data: Path, scenes: int, workers: int, cache: bool, batch: int, memoize: bool = False) -> dict[str, float]:
    """One epoch in this process; returns peak RSS (MB, process + workers) and images/s."""
    import torch

    from opnet.data.augment import DepthAugmenter
    from opnet.data.cache import build_scene_cache, default_cache_dir
    from opnet.data.scene_data import SceneData, SceneSamples
    from opnet.datasets import open_dataset
    from opnet.objects.config import object_from_config

    obj = object_from_config(json.loads((data / "object.json").read_text()))
    source = open_dataset(data)
    if scenes > len(source):
        source = Repeated(source, scenes)
    if cache:
        source = build_scene_cache(source, default_cache_dir(data, 256) if scenes <= len(open_dataset(data))
                                   else data.parent / f"{data.name}_x{scenes}_cache", 256, workers=2)  # fmt: skip
    elif memoize:
        source = Memoized(source)
    dm = SceneData(obj, data, batch_size=batch, num_workers=workers, augmenter=DepthAugmenter(), cache=False)
    keys = source.scenes()
    dm.splits = {"train": SceneSamples(source, [i for i, k in enumerate(keys) if k[1] > 0][:scenes], train=True,
                                       augmenter=DepthAugmenter())}  # fmt: skip
    peak = [0.0]
    done = threading.Event()

    def sample() -> None:
        while not done.is_set():
            me = os.getpid()
            peak[0] = max(peak[0], rss_mb([me, *child_pids(me)]))
            time.sleep(0.5)

    torch.manual_seed(0)
    watcher = threading.Thread(target=sample, daemon=True)
    watcher.start()
    start, n = time.perf_counter(), 0
    for b in dm.train_dataloader():
        n += len(b)
    elapsed = time.perf_counter() - start
    done.set()
    watcher.join()
    return {"images": n, "seconds": elapsed, "images_per_s": n / elapsed, "peak_rss_mb": peak[0]}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, required=True)
    parser.add_argument("--scenes", nargs="+", type=int, default=[5000, 50000])
    parser.add_argument("--workers", nargs="+", type=int, default=[0])
    parser.add_argument("--no-cache", action="store_true", help="read records from the dataset files")
    parser.add_argument("--memoize", action="store_true", help="keep records in memory (the former behaviour)")
    parser.add_argument("--batch", type=int, default=16)
    parser.add_argument("--out", type=Path, help="append the rows to this CSV (e.g. results/speed/data.csv)")
    parser.add_argument("--one", nargs=3, type=int, metavar=("SCENES", "WORKERS", "CACHE"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.one:
        print(json.dumps(run_one(args.data.resolve(), args.one[0], args.one[1], bool(args.one[2]), args.batch,
                                 args.memoize)))
        return 0
    rows = []
    for scenes in args.scenes:
        for workers in args.workers:
            cmd = [sys.executable, __file__, "--data", str(args.data), "--batch", str(args.batch),
                   "--one", str(scenes), str(workers), str(int(not args.no_cache))]  # fmt: skip
            cmd += ["--memoize"] if args.memoize else []
            out = subprocess.run(cmd, capture_output=True, text=True)
            if out.returncode:
                print(out.stderr[-3000:], file=sys.stderr)
                return out.returncode
            r = json.loads(out.stdout.strip().splitlines()[-1])
            rows.append((scenes, workers, r))
            print(f"  {scenes} scenes, {workers} workers: {r['images_per_s']:.0f} images/s, "
                  f"peak RSS {r['peak_rss_mb']:.0f} MB", flush=True)  # fmt: skip
    print("\n| scenes | source | DataLoader workers | images/s (one epoch) | peak RSS (MB) |")
    print("|---|---|---|---|---|")
    src = "scene cache" if not args.no_cache else "files, records kept" if args.memoize else "dataset files"
    for scenes, workers, r in rows:
        print(f"| {scenes} | {src} | {workers} | {r['images_per_s']:.0f} | {r['peak_rss_mb']:.0f} |")
    if args.out is not None:
        append_csv_rows(args.out, ["scenes", "source", "workers", "images_per_s", "peak_rss_mb"],
                    [[scenes, src, workers, f"{r['images_per_s']:.0f}", f"{r['peak_rss_mb']:.0f}"] for scenes, workers, r in rows])
    return 0


if __name__ == "__main__":
    sys.exit(main())
