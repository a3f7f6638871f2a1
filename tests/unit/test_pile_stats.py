"""Pile statistics of a generated dataset (scripts/bench/pile_stats.py): the bin's walls and how full the
drops make it, from the rig the dataset's generation.json records, computed here from the part's mesh, and
the parts the near clip plane cuts."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import pytest


def test_pile_stats_gives_the_walls_and_the_fill_of_the_recorded_bin(tiny_dataset: Path, tmp_path: Path) -> None:
    from opnet.objects import builtin_object
    from opnet.studies.scenes import pile_stats

    stats = pile_stats(tiny_dataset)  # 4 cycles x 4 drops of the zbracket, the default scene
    mesh = builtin_object("zbracket").mesh
    D = builtin_object("zbracket").diameter
    flat = sorted(mesh.extents)[1] * sorted(mesh.extents)[2]
    side = max(2.0 * D, math.sqrt(4 * flat / 1.5))  # the automatic floor: 4 drops lying flat in 1.5 layers
    wall = 0.6 * D  # the default bin_wall_factor
    assert stats["walls_mm"] == pytest.approx(1e3 * wall)
    assert stats["fill"] == pytest.approx(4 * mesh.convex_hull.volume / (side * side * wall))
    assert stats["height_max_mm"] > 0 and stats["full_piles"] == 4

    assert stats["clipped"] == 0.0  # the near clip plane above every pile

    other = tmp_path / "copy"  # a dataset opnet did not generate: no bin to report
    shutil.copytree(tiny_dataset, other)
    (other / "generation.json").unlink()
    params = json.loads((other / "parameter.json").read_text())
    params["clip_start"] = 0.999 * params["clip_end"]  # the near plane by the far one, below the floor: all cut
    (other / "parameter.json").write_text(json.dumps(params))
    stats = pile_stats(other)
    assert math.isnan(stats["fill"]) and math.isnan(stats["walls_mm"]) and stats["clipped"] == 1.0
