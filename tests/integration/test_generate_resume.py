"""Resume after SIGKILL, worker-count independence, and the generate.py entry logic."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

from opnet.cli.generate import run
from opnet.objects import builtin_object
from opnet.paths import config_dir
from opnet.synthesis import SceneConfig, generate_dataset
from opnet.synthesis.layout import bin_fill, make_rig

# 512 px: writing a cycle takes long enough (~0.1 s of PNG encoding) to be cut in the middle
ARGS = {"cycles": 4, "drops": 4, "seed": 11, "previews": 2, "progress": False}
SCENE = {"resolution": 512, "collision": "convex_hull"}

_CHILD = """
import sys
from opnet.objects import builtin_object
from opnet.synthesis import SceneConfig, generate_dataset
from opnet.synthesis.layout import bin_fill, make_rig
generate_dataset(builtin_object("zbracket"), sys.argv[1], workers=2, scene=SceneConfig(**{scene}), **{args})
"""


def tree_hashes(root: Path) -> dict[str, str]:
    """sha256 of every file under ``root``, by relative path (temporary files included)."""
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.mark.slow
def test_killed_run_resumes_to_the_same_bytes_with_any_worker_count(tmp_path: Path) -> None:
    killed = tmp_path / "killed"
    child = subprocess.Popen(
        [sys.executable, "-c", _CHILD.format(scene=SCENE, args=ARGS), str(killed)],
        start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 240
        while not list(killed.glob("gt/cycle_*/*.csv")):  # a cycle is being written: kill now
            assert child.poll() is None, "the generator ended before it could be killed"
            assert time.monotonic() < deadline, "the generator wrote no scene in time"
            time.sleep(0.002)
    finally:
        os.killpg(child.pid, signal.SIGKILL)  # the parent and its pool workers, mid-cycle
        child.wait()
    started = {p.name for sub in ("gt", "p_depth", "p_segmentation") for p in killed.glob(f"{sub}/cycle_*")}
    partial = [c for c in started if len(list(killed.glob(f"gt/{c}/*.csv"))) < ARGS["drops"] + 1]
    assert partial, "no cycle was cut short"
    obj = builtin_object("zbracket")
    resumed = generate_dataset(obj, killed, workers=1, scene=SceneConfig(**SCENE), **ARGS)
    assert resumed.cycles_generated >= 1  # at least one cycle was incomplete and was made again

    straight = tmp_path / "straight"
    generate_dataset(obj, straight, workers=1, scene=SceneConfig(**SCENE), **ARGS)
    two = tmp_path / "two_workers"
    generate_dataset(obj, two, workers=2, scene=SceneConfig(**SCENE), **ARGS)
    reference = tree_hashes(straight)
    assert len(reference) == 4 + 4 * 5 * 3 + 2  # root files, 20 scenes x 3 files, 2 previews
    assert tree_hashes(killed) == reference
    assert tree_hashes(two) == reference

    again = generate_dataset(obj, straight, workers=1, scene=SceneConfig(**SCENE), **ARGS)
    assert (again.cycles_skipped, again.cycles_generated) == (4, 0)
    assert tree_hashes(straight) == reference


def _compose(overrides: list[str]):
    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        return compose(config_name="generate", overrides=overrides)


def test_generate_entry_point_writes_a_dataset(tmp_path: Path) -> None:
    out = tmp_path / "pins"
    cfg = _compose(["object=pin", "scene=small", "scene.resolution=48", "cycles=2", "drops=2", f"out={out}",
                    "progress=false", "previews=1"])
    report = run(cfg)
    assert (report.cycles_generated, report.scenes_written) == (2, 6)
    assert (out / "object.json").read_text().count('"pin"') == 2
    assert sorted(p.name for p in (out / "gt").iterdir()) == ["cycle_0000", "cycle_0001"]


def test_scene_config_group_matches_the_dataclass_defaults() -> None:
    from omegaconf import OmegaConf

    cfg = _compose(["paths.root_dir=/tmp/opnet"])
    assert SceneConfig.from_dict(OmegaConf.to_container(cfg.scene)) == SceneConfig()
    assert str(cfg.out).endswith("outputs/data/bracket_c10_d20_s0_r512")
    with pytest.raises(ValueError, match="unknown keys.*fov"):
        SceneConfig.from_dict({"fov": 40})
    with pytest.raises(ValueError, match="width"):
        SceneConfig(resolution=64, width=63)


def test_a_mesh_without_faces_is_refused_naming_the_file(tmp_path: Path) -> None:
    mesh = tmp_path / "points_only.obj"
    mesh.write_text("v 0 0 0\nv 0.01 0 0\nv 0 0.01 0\n")
    cfg = _compose(["object=bunny", f"object.mesh={mesh}", f"out={tmp_path / 'ds'}", "progress=false"])
    with pytest.raises(ValueError, match="points_only.obj"):
        run(cfg)
    assert not (tmp_path / "ds").exists()


def _tiny(root: Path, cycles: int, **scene: object):
    """Generate (or complete) a dataset of ``cycles`` one-pin cycles at 32 pixels with ``scene`` keys."""
    return generate_dataset(builtin_object("pin"), root, cycles=cycles, drops=1, workers=1, progress=False, previews=0,
                            scene=SceneConfig(resolution=32, collision="convex_hull", **scene))


def test_a_complete_pybullet_dataset_is_used_by_the_mujoco_default_but_not_completed_by_it(tmp_path: Path) -> None:
    # a dataset made before MuJoCo became the default: generation.json without scene.physics
    root = tmp_path / "ds"
    _tiny(root, 2)
    gen_file = root / "generation.json"
    made = json.loads(gen_file.read_text())
    made["scene"].pop("physics")  # as pybullet-era datasets wrote it
    gen_file.write_text(json.dumps(made))
    # complete: used as it is, with the default engine's settings, and its generation.json kept
    report = _tiny(root, 2)
    assert report.cycles_skipped == 2 and json.loads(gen_file.read_text()) == made
    # a cycle to make: refused, naming the key and the engine it was made with
    with pytest.raises(ValueError, match=r"\['scene.physics'\] differ; to complete it, generate with scene.physics=pybullet"):
        _tiny(root, 3)
    # other settings still count on a complete dataset
    with pytest.raises(ValueError, match=r"\['scene.friction', 'scene.physics'\] differ"):
        _tiny(root, 2, friction=0.3)


def test_a_fill_cap_that_leaves_the_bin_keeps_the_dataset_and_one_that_widens_it_is_refused(tmp_path: Path) -> None:
    # a dataset made before a recipe set scene.bin_max_fill: where the cap leaves this part's bin as
    # it was, the piles are the same and the dataset is used and completed as it was made
    root = tmp_path / "ds"
    _tiny(root, 1)
    gen_file = root / "generation.json"
    made = json.loads(gen_file.read_text())
    assert "bin_max_fill" not in made["scene"]
    obj = builtin_object("pin")
    fill = bin_fill(obj, 1, make_rig(obj, 1, 1, SceneConfig(resolution=32, collision="convex_hull")).bin)
    report = _tiny(root, 2, bin_max_fill=min(1.0, 2 * fill))
    assert report.cycles_skipped == 1 and report.cycles_generated == 1
    assert json.loads(gen_file.read_text()) == made
    # a cap below the part's fill widens the floor: other piles, refused naming the key
    with pytest.raises(ValueError, match=r"generation.json: .*\['scene.bin_max_fill'\] differ"):
        _tiny(root, 2, bin_max_fill=fill / 2)
