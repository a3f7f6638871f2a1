"""Record the training scenes' clip planes in a checkpoint written before train.py recorded them.

    opnet-record-trained-clip <ckpt> [--data ROOT ...] (--write <file.ckpt> [--force] | --in-place)

train.py stores the clip planes of its training scenes' cameras in every checkpoint (``trained_clip``
of its settings entry, :mod:`opnet.run_settings`; the run config's ``trained_clip`` in checkpoints
written before that entry): predict.py and the ONNX runtime normalize a new image's depth with
them. For an older checkpoint this reads the planes from its training datasets (the config's
``data.root`` unless ``--data`` names them; their scenes must share one pair), writes them into a
copy (or the file itself with ``--in-place``) atomically, and reads it back. A refused checkpoint, a
missing dataset, a target that cannot be written or an existing ``--write`` file without ``--force`` is
one line ``error: <file>: <problem>`` with exit status 2, and leaves the target as it was and no
temporary file.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

from opnet.arguments import ArgumentParser  # noqa: E402
from opnet.cli.build import load_checkpoint, read_checkpoint  # noqa: E402
from opnet.cli.tools import require_writable, save_checkpoint, tool_main  # noqa: E402
from opnet.data.scene_data import ConcatScenes, SceneSamples, as_paths  # noqa: E402
from opnet.datasets import open_dataset  # noqa: E402
from opnet.run_settings import CHECKPOINT_KEY

#: scenes whose cameras are read, spread over the datasets
PROBES = 64


def datasets_clip(roots: list[Path]) -> tuple[float, float]:
    """The one pair of clip planes of the datasets' scenes.

    Raises:
        ValueError: a dataset is missing, or the scenes' planes differ.
    """
    for root in roots:
        if root.exists() and not root.is_dir():
            raise ValueError(f"{root}: a file, not a dataset folder (give the training datasets with --data)")
        if not root.is_dir():
            raise ValueError(f"{root}: training dataset not found (give the datasets with --data)")
    sources = [open_dataset(root) for root in roots]
    source = sources[0] if len(sources) == 1 else ConcatScenes(sources)
    planes = SceneSamples(source, range(len(source))).clip_planes(PROBES)
    if planes is None:
        raise ValueError(f"{', '.join(map(str, roots))}: the scenes' cameras have several clip planes (or there are "
                         "no scenes): no one normalization to record")
    return planes


def record(src: Path, dest: Path, roots: list[Path] | None = None) -> tuple[float, float]:
    """Write ``src`` with its training planes recorded to ``dest`` (may be ``src``); the planes."""
    ckpt = read_checkpoint(src)
    system, cfg = load_checkpoint(src)
    planes = datasets_clip(roots or as_paths(cfg.data.get("root")))
    ckpt["hyper_parameters"]["config"]["trained_clip"] = [float(planes[0]), float(planes[1])]
    if CHECKPOINT_KEY in ckpt:  # the settings the checkpoint is read with
        ckpt[CHECKPOINT_KEY] = system.settings.with_trained_clip(planes).to_dict()
    save_checkpoint(ckpt, dest)
    if load_checkpoint(dest)[0].settings.input.trained_clip != planes:
        raise ValueError(f"{dest}: the written checkpoint does not read back with trained_clip {planes}")
    return planes


def main(argv: list[str] | None = None) -> int:
    ap = ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("ckpt", type=Path)
    ap.add_argument("--data", type=Path, nargs="+", default=None, help="the training datasets (default: the config's)")
    where = ap.add_mutually_exclusive_group(required=True)
    where.add_argument("--write", type=Path, help="the copy to write")
    where.add_argument("--in-place", action="store_true", help="rewrite the checkpoint itself")
    ap.add_argument("--force", action="store_true", help="replace an existing --write file")
    args = ap.parse_args(argv)
    dest = args.ckpt if args.in_place else args.write

    def body() -> int:
        option = "--in-place" if args.in_place else "--write"
        planes = record(args.ckpt, require_writable(dest, option, replace=args.in_place or args.force), args.data)
        print(f"{dest}: trained_clip [{planes[0]:g}, {planes[1]:g}] m")
        return 0

    return tool_main(body)


if __name__ == "__main__":
    sys.exit(main())
