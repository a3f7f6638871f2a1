"""The three real frames of IPD object 18 (``<shared>/data/ipd_real_obj18``) as the real-frame studies
score them: where they are, the region of interest and clip planes around the basket, eval.py of a
checkpoint on a split of them, and what a training run was."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from opnet.paths import shared_dir
from opnet.studies import run_logged

FRAMES = shared_dir() / "data" / "ipd_real_obj18"
OBJECT_ID = 18
#: the region of interest (pixels of the 2064 x 1544 frames) around the basket, found from the frames'
#: depth alone, and the working clip planes around it (metres)
ROI = [560, 230, 1250, 1160]
CLIP = [1.55, 2.05]
#: the search starts from every hypothesis the network decodes, not from their DBSCAN averages (an average
#: of a right and a turned hypothesis is neither; measured: results/real_ipd/search_ab.md)
SEARCH_DECODING = ["+decoding.averaging=false"]


def evaluate(ckpt: Path, split: Path, out: Path, roi: list[int], clip: list[float], overrides: list[str],
             examples: int = 3) -> dict[str, Any]:  # fmt: skip
    """``eval.py`` of ``ckpt`` on a BOP split of the frames (ROI, clip planes, the dataset's own
    resolution) with further ``overrides``; its summary."""
    split = split.resolve()  # read whole as the test split (data.root too: nothing else is opened)
    run_logged([sys.executable, "eval.py", f"ckpt={ckpt}", f"data.root={split}", f"data.test_root={split}",
                f"+data.object_id={OBJECT_ID}", f"+data.roi=[{','.join(map(str, roi))}]", f"+data.clip=[{clip[0]},{clip[1]}]",
                "+data.cache=false", f"out={out}", f"examples={examples}", *overrides], out.with_suffix(".log"))  # fmt: skip
    return json.loads((out / "summary.json").read_text())


def run_info(run: Path) -> tuple[str, str]:
    """(training seed, parameterization name) of a run folder of train.py, from its logged
    hyperparameters ('?' where they are not there)."""
    import re

    path = run / "tensorboard" / "hparams.yaml"
    hp = path.read_text() if path.is_file() else ""
    seed = re.search(r"^  seed: (\d+)$", hp, re.MULTILINE)
    param = re.search(r"parameterization:\n\s+_target_: opnet\.parameterizations\.\w+\.(\w+)Parameterization", hp)
    return (seed.group(1) if seed else "?"), (param.group(1) if param else "?")


__all__ = ["CLIP", "FRAMES", "OBJECT_ID", "ROI", "SEARCH_DECODING", "evaluate", "run_info"]
