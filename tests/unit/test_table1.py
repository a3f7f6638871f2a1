"""scripts/experiments/table1/table1.py: the request is checked, the arms are the grid, the table has the spread and the paper."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest
import yaml

from opnet.paths import REPO_ROOT

spec = importlib.util.spec_from_file_location("table1", REPO_ROOT / "scripts" / "experiments" / "table1" / "table1.py")
table1 = importlib.util.module_from_spec(spec)
spec.loader.exec_module(table1)


@pytest.mark.parametrize(("argv", "message"), [
    (["--objects", "bunny,teapot"], r"--objects: unknown \['teapot'\]; expected some of \["),
    (["--parameterizations", "vanilla,quaternion"], r"--parameterizations: unknown \['quaternion'\]"),
    (["--seeds"], r"--seeds: none given"),
    (["--seeds", "0", "0"], r"--seeds \[0, 0\]: expected distinct integers >= 0"),
    (["--steps", "0"], r"--steps 0: expected an integer >= 1"),
    (["--jobs", "0"], r"--jobs 0: expected an integer >= 1"),
])
def test_a_bad_request_is_one_line(argv: list[str], message: str, capsys: pytest.CaptureFixture) -> None:
    assert table1.main([*argv, "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ")
    assert __import__("re").search(message, err), err


def test_the_arms_are_the_grid_of_objects_parameterizations_and_seeds(capsys: pytest.CaptureFixture) -> None:
    assert table1.main(["--objects", "bunny,pin", "--parameterizations", "vanilla,ap", "--seeds", "0", "1",
                        "--steps", "7", "--dry-run"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 8 and all("experiment=table1" in x and "trainer.max_steps=7" in x for x in lines)
    assert lines[0].endswith("outputs/table1/vanilla_bunny_s0") and "object=pin" in lines[-1] and "seed=1" in lines[-1]


def _arm(root: Path, param: str, obj: str, seed: int, ap: float) -> None:
    run = root / f"{param}_{obj}_s{seed}"
    (run / ".hydra").mkdir(parents=True)
    (run / "test").mkdir()
    (run / ".hydra" / "hydra.yaml").write_text(
        yaml.safe_dump({"hydra": {"runtime": {"choices": {"parameterization": param, "object": obj}}}}))
    (run / ".hydra" / "config.yaml").write_text(yaml.safe_dump({"seed": seed}))
    diag = {"to_find": 100, "matched": round(100 * ap), "t_err_mm_p50": 2.0, "r_err_deg_p50": 4.0}
    (run / "test" / "summary.json").write_text(json.dumps({"ap": ap, "map": ap, "f1": ap, "diagnostics": diag}))


def test_arms_at_once_each_build_their_own_cache_and_all_run(tmp_path: Path) -> None:
    """``--jobs``: concurrent arms get a scene cache each (one shared cache would be built by all at once);
    every arm runs once, a finished one is skipped, and a failed one is named."""
    args = table1.parse(["--objects", "bunny", "--parameterizations", "vanilla,ap,si", "--seeds", "0",
                         "--runs-dir", str(tmp_path), "--jobs", "3"])
    todo = table1.arms(args)
    assert [c for _, cmd in todo for c in cmd if c.startswith("data.cache_dir=")] == [
        f"data.cache_dir={run / 'cache'}" for run, _ in todo]
    script = ("import pathlib, sys, time; time.sleep(0.3); run = pathlib.Path(sys.argv[1]); "
              "(run / 'test').mkdir(); (run / 'test' / 'summary.json').write_text('{}'); "
              "(run / 'started').write_text(str(time.time())); sys.exit(run.name.startswith('si'))")
    fake = [(run, [table1.sys.executable, "-c", script, str(run)]) for run, _ in todo]
    (tmp_path / "vanilla_bunny_s0" / "test").mkdir(parents=True)
    (tmp_path / "vanilla_bunny_s0" / "test" / "summary.json").write_text("{}")  # finished before: not run again
    assert table1.run_arms(fake, jobs=3) == ["si_bunny_s0"]
    assert not (tmp_path / "vanilla_bunny_s0" / "started").exists()
    assert (tmp_path / "ap_bunny_s0" / "started").exists() and (tmp_path / "si_bunny_s0" / "console.log").exists()


def test_collect_writes_mean_sd_paper_and_the_checks(tmp_path: Path) -> None:
    runs, out = tmp_path / "runs", tmp_path / "results"
    for obj, van, ap in (("bunny", (0.7, 0.8, 0.9), (0.8, 0.85, 0.9)), ("ring_screw", (0.6, 0.6, 0.6), (0.5, 0.5, 0.5))):
        for seed in range(3):
            _arm(runs, "vanilla", obj, seed, van[seed])
            _arm(runs, "ap", obj, seed, ap[seed])
    _arm(runs, "ap", "gear_shaft", 5, 0.99)  # not part of this request: left out
    argv = ["--objects", "bunny,ring_screw", "--parameterizations", "vanilla,ap", "--runs-dir", str(runs),
            "--out", str(out), "--collect"]
    assert table1.main(argv) == 0
    text = (out / "README.md").read_text()
    assert "| vanilla | 0.800 ± 0.100 (3) [0.92] | 0.600 ± 0.000 (3) [0.88] |" in text
    assert "| ap | 0.850 ± 0.050 (3) [0.92] | 0.500 ± 0.000 (3) [0.96] |" in text
    assert "gear_shaft" not in text and "Arms finished" not in text  # all 12 asked for are there
    assert "- ap >= vanilla on 1 of 2 objects (bunny); needed 2: does not hold" in text
    rows = (out / "table1.csv").read_text().splitlines()
    assert table1.main([*argv[:-1], "--seeds", "0", "1", "2", "3", "--collect"]) == 0
    assert "**Arms finished: 12 of 16.**" in (out / "README.md").read_text()
    assert rows[0].startswith("decoding,parameterization,object,runs,ap_mean,ap_sd,paper") and len(rows) == 5
    assert "tuned per arm" not in text  # no arm has a checkpoint to tune: the block is left out


def test_an_arm_a_time_limit_stopped_is_marked_and_the_merge_keeps_the_mark(tmp_path: Path) -> None:
    """An arm that ``trainer.max_time`` stopped is not at the budget: arms.csv marks it with the step of
    its last validation, the README counts it, ``--machine`` names where the arms ran, and a merged
    table repeats the count beside its source."""
    runs, out = tmp_path / "runs", tmp_path / "gpu"
    for seed, step in ((0, 1320), (1, 1021)):
        _arm(runs, "eve", "pepper", seed, 0.7)
        run = runs / f"eve_pepper_s{seed}"
        (run / "learning_curve.csv").write_text(f"epoch,step,train_minutes\n0,60,0.1\n20,{step},2.8\n")
        (run / "console.log").write_text("...\nTime limit reached. Elapsed time is 0:03:50.\n" if seed else "...\n")
    assert table1.main(["--objects", "pepper", "--parameterizations", "eve", "--seeds", "0", "1", "--runs-dir",
                        str(runs), "--out", str(out), "--collect", "--machine", "a lent GPU"]) == 0
    arms = (out / "arms.csv").read_text().splitlines()
    assert arms[0].endswith(",machine,steps,time_limited")
    assert arms[1].endswith(",a lent GPU,1320,0") and arms[2].endswith(",a lent GPU,1021,1")
    text = (out / "README.md").read_text()
    assert "**1 of 2 arms stopped short of the 1350 steps (a time limit)" in text and "came at 1021-1021 steps" in text
    assert "Machine: a lent GPU" in text
    table1.main(["--combine", str(out), "--out", str(tmp_path / "merged")])
    merged = (tmp_path / "merged" / "README.md").read_text()
    assert "machine: a lent GPU; **1 of 2 arms stopped short of the 1350 steps" in merged


def test_decoding_tuned_per_arm_is_a_second_table_with_its_own_checks(tmp_path: Path) -> None:
    runs, out = tmp_path / "runs", tmp_path / "results"
    for seed in range(2):
        _arm(runs, "vanilla", "bunny", seed, 0.5)
        _arm(runs, "ap", "bunny", seed, 0.4)
        for param, tuned in (("vanilla", 0.55), ("ap", 0.6 + 0.1 * seed)):  # what tuning on val would cache
            (runs / f"{param}_bunny_s{seed}" / "decoding_tuned.json").write_text(json.dumps(
                {"settings": {"score": "p"}, "ap": tuned, "found": 0.5, "t_err_mm_p50": 3.0, "r_err_deg_p50": 5.0}))
    argv = ["--objects", "bunny", "--parameterizations", "vanilla,ap", "--seeds", "0", "1", "--runs-dir", str(runs),
            "--out", str(out), "--collect"]
    assert table1.main(argv) == 0
    configured, tuned = (out / "README.md").read_text().split("tuned per arm")
    assert "| ap | 0.400 ± 0.000 (2) [0.92] |" in configured and "ap >= vanilla on 0 of 1" in configured
    assert "| ap | 0.650 ± 0.071 (2) [0.92] |" in tuned and "ap >= vanilla on 1 of 1 objects (bunny)" in tuned
    rows = (out / "table1.csv").read_text().splitlines()
    assert sum(r.startswith("tuned on val,ap,bunny,2,0.6500") for r in rows) == 1


def test_arms_csv_keeps_every_seed_with_its_tuned_score_and_the_machine() -> None:
    rows = [{"parameterization": "z", "object": "bunny", "seed": s, "ap": 0.5 + s / 10, "found": 0.4, "t_err_mm_p50": 3.0,
             "r_err_deg_p50": 2.0, "run": f"z_bunny_s{s}"} for s in (1, 0)]
    lines = table1.arms_csv(rows, [{"run": "z_bunny_s1", "ap": 0.65, "found": 0.5}]).splitlines()
    assert lines[0].startswith("parameterization,object,seed,ap,") and len(lines) == 3
    assert lines[1].startswith("z,bunny,0,0.500000,") and ",,," in lines[1]  # seed 0: not tuned
    assert lines[2].startswith("z,bunny,1,0.600000,") and ",0.650000,0.500000,z_bunny_s1," in lines[2]
    assert lines[2].endswith(table1.machine()) or table1.machine() in lines[2]


def test_combine_merges_tables_of_two_machines_naming_each_rows_source(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    old, new, out = tmp_path / "old", tmp_path / "new", tmp_path / "all"
    for folder, params, recorded in ((old, ("vanilla", "ap"), False), (new, ("z", "vanilla"), True)):
        runs = tmp_path / f"runs_{folder.name}"
        for p in params:
            for seed in range(3):
                _arm(runs, p, "bunny", seed, {"vanilla": 0.5, "ap": 0.6, "z": 0.55}[p] + (0.01 * seed if folder == new else 0))
        assert table1.main(["--objects", "bunny", "--parameterizations", ",".join(params), "--runs-dir", str(runs),
                            "--out", str(folder), "--collect", "--no-tune"]) == 0
        if not recorded:  # a table of this script names its machine; an older one may not
            (folder / "README.md").write_text("".join(x for x in (folder / "README.md").read_text().splitlines(True)
                                                      if not x.startswith("Machine:")))
    assert table1.main(["--combine", str(old), str(new), "--out", str(out)]) == 0
    text = (out / "README.md").read_text()
    assert "- [1] [`../old/`](../old/README.md): vanilla, ap; machine: not recorded" in text
    assert f"- [2] [`../new/`](../new/README.md): vanilla, z; machine: {table1.machine()}\n" in text
    # the paper's order; vanilla from the first table, z from the second
    assert text.index("| vanilla | 0.500 ± 0.000 (3) [0.92] | [1] |") < text.index("| ap | 0.600") < text.index("| z | 0.560 ± 0.010 (3) [0.85] | [2] |")
    assert "- ap >= vanilla on 1 of 1 objects (bunny); needed 1: holds" in text
    assert "| configured | vanilla | bunny | 0.500 ± 0.000 (3) [1] | 0.510 ± 0.010 (3) [2] |" in text
    rows = (out / "table1.csv").read_text().splitlines()
    assert rows[0].endswith(",source") and len(rows) == 4 and rows[3].startswith("configured,z,bunny,3,0.56") and rows[3].endswith(",2")
    capsys.readouterr()
    assert table1.main(["--combine", str(tmp_path / "nothing"), "--out", str(out)]) == 2
    assert "--combine: no table1.csv in" in capsys.readouterr().err
