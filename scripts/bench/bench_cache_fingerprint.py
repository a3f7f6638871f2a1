"""Cost of the scene cache's fingerprint (:func:`opnet.data.cache.source_fingerprint`): one ``stat``
per source file of every scene, done each time a training or evaluation opens its cached dataset.

    python scripts/bench/bench_cache_fingerprint.py [--scenes 50000] [--drops 30] [--root <dataset>]

Without ``--root`` it writes a fake IPA dataset of ``--scenes`` scenes (three small files each, in
cycles of ``--drops + 1`` scenes) into a temporary folder, deleted afterwards. It prints the time
to list the scenes (opening the dataset) and to fingerprint them, in seconds per 10,000 scenes
(best of ``--repeat``; the file metadata is in the page cache, as after the first epoch or a
recent generation: a cold cache on a network file system costs more).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from opnet.data.cache import scene_keys, source_fingerprint
from opnet.datasets import open_dataset
from opnet.datasets.ipa import scene_paths
from opnet.datasets.ipa_params import IPAParameters, write_parameters


def write_fake_dataset(root: Path, scenes: int, drops: int) -> None:
    """An IPA layout of ``scenes`` scenes whose files hold a few bytes (only their metadata counts)."""
    cycles = -(-scenes // (drops + 1))
    write_parameters(root, IPAParameters(50.0, 0.5, 1.5, 64, 64, 64, 0, 0, cycles, drops))
    for i in range(scenes):
        cycle, n = divmod(i, drops + 1)
        for path in scene_paths(root, cycle, n).values():
            if n == 0:
                path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(b"x" * (16 + n))


def best_of(repeat: int, fn) -> tuple[float, object]:
    """The smallest wall time of ``repeat`` calls of ``fn`` and its last result."""
    best, result = float("inf"), None
    for _ in range(repeat):
        start = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - start)
    return best, result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", type=int, default=50_000)
    ap.add_argument("--drops", type=int, default=30)
    ap.add_argument("--root", type=Path, help="an existing dataset instead of a fake one")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="fingerprint_") as tmp:
        root = args.root
        if root is None:
            root = Path(tmp) / "fake"
            start = time.perf_counter()
            write_fake_dataset(root, args.scenes, args.drops)
            print(f"wrote {args.scenes} fake scenes in {time.perf_counter() - start:.1f} s")
        t_open, source = best_of(args.repeat, lambda: open_dataset(root))
        keys = scene_keys(source)
        files = len(source.source_files())
        t_print, digest = best_of(args.repeat, lambda: source_fingerprint(source, keys))
        per = 10_000 / max(len(keys), 1)
        print(f"{root}: {len(keys)} scenes, {files} source files, fingerprint {digest}")
        print(f"  listing the scenes: {t_open:.3f} s ({t_open * per:.3f} s per 10,000 scenes)")
        print(f"  fingerprint:        {t_print:.3f} s ({t_print * per:.3f} s per 10,000 scenes)")


if __name__ == "__main__":
    main()
