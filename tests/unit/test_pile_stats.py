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


def test_keep_leaves_the_rows_of_datasets_not_given_on_the_page(tiny_dataset: Path, tmp_path: Path,
                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    import importlib.util
    import shlex
    import sys

    from opnet.paths import REPO_ROOT

    spec = importlib.util.spec_from_file_location("pile_stats_script", REPO_ROOT / "scripts" / "bench" / "pile_stats.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    a, b, page = tmp_path / "set_a", tmp_path / "set_b", tmp_path / "piles.md"
    shutil.copytree(tiny_dataset, a)
    shutil.copytree(tiny_dataset, b)

    def run(*args: str) -> list[str]:
        monkeypatch.setattr(sys, "argv", ["pile_stats.py", *args])
        script.main()
        lines = page.read_text().splitlines()
        return [line.split("|")[1].strip() for line in lines if line.startswith("| ") and "---" not in line][1:]

    assert run(str(a), "--out", str(page), "--title", "T") == ["set_a"]
    row_a = next(line for line in page.read_text().splitlines() if line.startswith("| set_a"))
    shutil.rmtree(a)  # gone from disk: its measured row stays
    assert run(str(b), "--out", str(page), "--title", "T", "--keep") == ["set_a", "set_b"]
    assert row_a in page.read_text().splitlines()
    command = shlex.split(page.read_text().splitlines()[2])
    assert command[:4] == ["python", "scripts/bench/pile_stats.py", str(a), str(b)] and command.count("--out") == 1
    assert run(str(b), "--out", str(page), "--title", "T") == ["set_b"]  # without --keep: what is given
