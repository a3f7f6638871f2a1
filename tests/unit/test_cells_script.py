"""scripts/experiments/cells/cells.py: the cell's camera at another resolution sees the same rays, and S of auto:S holds the
basket in any yaw."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest

from opnet.paths import REPO_ROOT

spec = importlib.util.spec_from_file_location("cells", REPO_ROOT / "scripts" / "experiments" / "cells" / "cells.py")
cells = importlib.util.module_from_spec(spec)
spec.loader.exec_module(cells)


def test_the_half_resolution_camera_sees_the_same_rays(shared: Path, tmp_path: Path) -> None:
    from opnet.datasets.camera_file import read_camera_file

    full = read_camera_file(cells.camera_file(1.0, tmp_path / "x1.yaml"))
    half = read_camera_file(cells.camera_file(0.5, tmp_path / "x05.yaml"))
    assert (half.width, half.height) == (full.width // 2, full.height // 2)
    assert (half.clip_start, half.clip_end) == cells.CLIP
    # a pixel corner of the half image and the same corner of the full one: one ray
    for u, v in ((-0.5, -0.5), (half.width - 0.5, half.height - 0.5)):
        ray_half = ((u - half.cx) / half.fx, (v - half.cy) / half.fy)
        U, V = 2 * (u + 0.5) - 0.5, 2 * (v + 0.5) - 0.5
        ray_full = ((U - full.cx) / full.fx, (V - full.cy) / full.fy)
        assert np.allclose(ray_half, ray_full, atol=1e-9)


def test_the_roi_side_holds_the_basket_in_any_yaw() -> None:
    t = cells.BASKET["bin_wall_thickness"]
    diagonal = math.hypot(cells.BASKET["bin_inner"] + 2 * t, cells.BASKET["bin_inner_y"] + 2 * t)
    assert diagonal * 1.1 <= cells.roi_side() < diagonal * 1.1 + 0.05
    assert cells.ARMS["auto"]["roi"] == f"auto:{cells.roi_side():g}"


@pytest.mark.parametrize("arm", ["auto", "frame128"])
def test_each_arm_is_a_policy_of_the_table(arm: str) -> None:
    assert cells.arm_policy(arm) in (cells.ARMS[arm]["roi"], "working area (whole frame)")


def test_the_seed_table_gives_mean_sd_and_the_gap_for_policies_with_seeds() -> None:
    rows = [{"policy": "auto:0.8", "refine": "search", "placement": p, "ap": ap}
            for p, ap in (("trained", 0.50), ("trained", 0.46), ("moved", 0.45), ("moved", 0.47))]
    rows += [{"policy": "fixed", "refine": "search", "placement": "trained", "ap": 0.5},  # one seed: left out
             {"policy": "fixed", "refine": "search", "placement": "moved", "ap": 0.1}]
    lines = cells.seed_table(rows)
    assert lines[-1] == "| auto:0.8 | search | 2 | 0.480 ± 0.028 | 0.460 ± 0.014 | -0.020 (within 0.05) |"
    assert not any("fixed" in line for line in lines)
    assert cells.seed_table(rows[4:]) == []
    # two input sizes of one policy are no seeds of one arm
    sizes = [{**r, "model": f"frame{n} (input {n}, seed 0)"} for r, n in zip(rows[:4], (128, 256, 128, 256), strict=True)]
    assert cells.seed_table(sizes) == []
    # one model scored on the study's piles and on the same piles written within its own planes: no seeds either
    planes = [{**r, "model": m} for r, m in zip(rows[:4], ("cell_x (cell=x, seed 0)", "cell_x (cell=x, seed 0), piles "
                                                           "within its planes 1.3-2.1 m") * 2, strict=True)]
    assert cells.seed_table(planes) == []
    # an arm that changes the loss is no seed of the recipe's arm; the recipe's seeds are
    arms = [{**r, "model": m} for r, m in zip(rows[:4], ("auto (input 128, seed 0)", "auto_lz10 (input 128, seed 0)",
                                                          "auto (input 128, seed 0)", "auto_lz10 (input 128, seed 0)"), strict=True)]
    assert cells.seed_table(arms) == []
    seeds = [{**r, "model": m} for r, m in zip(rows[:4], ("auto (input 128, seed 0)", "auto_s1 (input 128, seed 1)",
                                                           "auto (input 128, seed 0)", "auto_s1 (input 128, seed 1)"), strict=True)]
    assert cells.seed_table(seeds)[-1] == lines[-1]


def test_a_cell_file_model_is_scored_on_the_same_piles_written_within_its_own_planes(
        shared: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    # the study's piles are written within its planes: a model whose cell file measured others (a surface beyond
    # its far plane at its far plane) is scored on the same piles (seeds, settings) written within its own
    own = cells.cell_file_clip("ipd_area")
    assert cells.piles_of("auto") == {"": cells.CLIP}
    assert cells.piles_of("cell_ipd_area") == {"": cells.CLIP, "_own_planes": own}
    study, mine = cells.datasets(tmp_path, 200, 12)[1], cells.datasets(tmp_path, 200, 12, own)[1]
    calls: list[tuple] = []
    monkeypatch.setattr(cells, "generate", lambda camera, root, cycles, views, seed, scale, logs, **scene:
                        calls.append((Path(camera), root, cycles, seed, scene)))
    cells.generate_tests(tmp_path, study, cells.CLIP, tmp_path)
    cells.generate_tests(tmp_path, mine, own, tmp_path)
    half = len(calls) // 2
    assert half == 5 and len(calls) == 10
    for a, b in zip(calls[:half], calls[half:], strict=True):
        assert a[1] != b[1] and a[2:] == b[2:]  # other folders, the same piles
    from opnet.datasets.camera_file import read_camera_file

    assert (read_camera_file(calls[0][0]).clip_start, read_camera_file(calls[0][0]).clip_end) == cells.CLIP
    assert (read_camera_file(calls[-1][0]).clip_start, read_camera_file(calls[-1][0]).clip_end) == own


def test_the_one_command_leaves_the_steps_to_the_recipe_and_is_scored_with_the_refinement_it_records(
        shared: Path) -> None:  # fmt: skip
    # the shipped model is the one command as a user runs it: no steps given, so the flat plate trains the flat
    # part's steps and records its search; the study scores it with that search too
    from opnet.cli.sizing import settings_for_flat_part
    from opnet.cli.train import plain
    from opnet.objects.config import object_from_config
    from opnet.studies import compose_train

    given = cells.cell_overrides(200, 2, 0.5, None)
    assert not any(o.startswith("trainer.max_steps") for o in given)
    assert "trainer.max_steps=3000" in cells.cell_overrides(200, 2, 0.5, 3000)
    cfg = compose_train(given)
    assert settings_for_flat_part(cfg, object_from_config(plain(cfg.object)).mesh) is not None
    assert cfg.trainer.max_steps == cfg.flat_part.max_steps and cfg.deploy_refine == cells.CELL_REFINE
    assert cells.CELL_ARM in cells.REFINE_OF[cells.CELL_REFINE]


def test_the_budget_trains_the_recipe_at_each_multiple_of_its_steps_validating_as_often(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    import subprocess

    from opnet.studies import compose_train

    # the 1 x budget is the one command's own: experiment=cell's steps for a flat part
    assert compose_train(cells.cell_overrides(200, 2, 0.5, None)).flat_part.max_steps == cells.RECIPE_STEPS
    seen = []
    monkeypatch.setattr(subprocess, "run", lambda cmd, **kw: seen.append(cmd) or subprocess.CompletedProcess(cmd, 0))
    last = cells.budget_dir(tmp_path, 2) / "checkpoints" / "last.ckpt"  # x2 stopped part-way before: it resumes
    last.parent.mkdir(parents=True)
    last.write_bytes(b"")
    assert cells.train_budget(tmp_path, [1, 2, 4], 3, 200, 2, 0.5, ["trainer=gpu"], val_every=2) == []
    by_dir = {Path(next(a for a in cmd if a.startswith("hydra.run.dir=")).split("=", 1)[1]).name: cmd for cmd in seen}
    assert sorted(by_dir) == ["x1", "x2", "x4"]
    for m in (1, 2, 4):
        cmd = by_dir[f"x{m}"]
        assert f"trainer.max_steps={cells.RECIPE_STEPS * m}" in cmd
        assert f"trainer.check_val_every_n_epoch={2 * m}" in cmd
        assert cmd.index("trainer=gpu") > cmd.index(f"trainer.max_steps={cells.RECIPE_STEPS * m}")  # extra comes last
        assert (f"ckpt_path={last}" in cmd) == (m == 2)
        cfg = compose_train([a for a in cmd[2:] if not a.startswith(("hydra.", "ckpt_path="))])
        assert cfg.trainer.max_steps == cells.RECIPE_STEPS * m and cfg.trainer.accelerator == "gpu"


def test_the_budget_page_scores_each_best_checkpoint_and_keeps_what_was_scored(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    import csv
    import json

    runs = tmp_path / "runs"
    for m, aps in ((1, [0.2, 0.5, 0.4]), (2, [0.1, 0.3, 0.6])):
        run = runs / "budget" / f"x{m}"
        (run / "checkpoints").mkdir(parents=True)
        (run / "checkpoints" / "epoch001-ap0.5000.ckpt").write_bytes(b"")
        rows = [f"{k},{200 * m * (k + 1)},{k},0,{ap}," for k, ap in enumerate(aps)]
        (run / "learning_curve.csv").write_text("epoch,step,train_minutes,images,val_ap,test_ap\n" + "\n".join(rows) + "\n")
    summary = {"num_scenes": 3, "ap": 0.42, "diagnostics": {"to_find": 10, "matched": 5, "t_err_mm_p50": 2.0,
                                                            "r_err_deg_p50": 3.0}}  # fmt: skip
    scored = []

    def evaluate(ckpt: Path, roots: list, out: Path, overrides: list) -> dict:
        scored.append(out.name)
        out.mkdir(parents=True)
        (out / "summary.json").write_text(json.dumps(summary))
        return summary

    monkeypatch.setattr(cells, "evaluate", evaluate)
    out = tmp_path / "results"
    assert cells.budget_report(runs, tmp_path / "data", 200, 12, out, "here") == 0
    assert len(scored) == 2 * len(cells.BUDGET_REFINES) * 2  # budgets x placements x refinements
    rows = list(csv.DictReader((out / "budget.csv").open()))
    best = {r["multiple"]: (r["best_val_ap"], r["best_step"], r["steps_done"]) for r in rows}
    assert best == {"1": ("0.5", "400", "600"), "2": ("0.6", "1200", "1200")}
    assert len(list(csv.DictReader((out / "budget_curve.csv").open()))) == 6
    assert "| 2 x | 1200 of 12000 | 0.600 (1200) |" in (out / "budget.md").read_text()
    scored.clear()
    assert cells.budget_report(runs, tmp_path / "data", 200, 12, out, "here") == 0 and scored == []  # kept


def test_a_budget_without_whole_numbers_is_one_line_exit_2(shared: Path, capsys: pytest.CaptureFixture) -> None:
    assert cells.main(["--stage", "budget", "--jobs", "0"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: --jobs 0") and "\n" not in err


def test_what_a_gpu_call_brought_back_is_placed_where_the_budget_page_reads_it(tmp_path: Path) -> None:
    import tarfile

    from opnet.paths import best_checkpoint

    back, runs = tmp_path / "back", tmp_path / "runs"
    (back / "budget" / "x2").mkdir(parents=True)
    (back / "budget" / "x2" / "learning_curve.csv").write_text("epoch,step,train_minutes,images,val_ap,test_ap\n")
    with tarfile.open(back / "budget.tar.gz", "w:gz") as tar:
        tar.add(back / "budget", arcname="budget")
    (back / "budget_x2_epoch007-ap0.5500.ckpt").write_bytes(b"weights")
    placed = cells.collect_budget(back, runs)
    assert placed == [cells.budget_dir(runs, 2) / "checkpoints" / "epoch007-ap0.5500.ckpt"]
    assert best_checkpoint(cells.budget_dir(runs, 2)) == placed[0] and placed[0].read_bytes() == b"weights"
    assert (cells.budget_dir(runs, 2) / "learning_curve.csv").is_file()
    with pytest.raises(SystemExit, match="budget.tar.gz"):
        cells.collect_budget(tmp_path / "nothing", runs)
