"""Scene settings have one address, ``scene.*``, in ``generate.py`` and ``train.py``: the same
overrides compose to the same :class:`opnet.synthesis.SceneConfig` in both, and the old address set
apart is refused naming the key to use."""

from __future__ import annotations

import dataclasses

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from opnet.cli.build import check_scene_address
from opnet.paths import config_dir
from opnet.synthesis import SceneConfig


def _compose(name: str, overrides: list[str]) -> object:
    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        return compose(config_name=name, overrides=overrides)


def _scene(cfg: object) -> SceneConfig:
    return SceneConfig.from_dict(OmegaConf.to_container(cfg.scene, resolve=True))


@pytest.mark.parametrize("overrides", [
    ["scene.resolution=200"],
    ["scene=bulk", "scene.views=3", "scene.camera_tilt_deg=10.0", "scene.bin_area=[-0.1,-0.1,0.1,0.1]"],
    ["scene=small", "scene.clutter=4", "scene.outside_clip=clamp"],
])  # fmt: skip
def test_the_same_overrides_make_the_same_scene_in_generate_and_train(overrides: list[str]) -> None:
    made = _scene(_compose("generate", overrides))
    train = _compose("train", overrides)
    used = SceneConfig.from_dict(OmegaConf.to_container(train.data.generate, resolve=True)["scene"])
    assert used == made == _scene(train)
    assert train.data.root.endswith(f"_r{made.resolution}")  # the data folder is named after the scene used
    check_scene_address(train)


def test_train_defaults_to_the_generators_scene_at_256_pixels() -> None:
    generator, train = _scene(_compose("generate", [])), _scene(_compose("train", []))
    assert (generator.resolution, train.resolution) == (512, 256)
    assert dataclasses.replace(train, resolution=512) == generator


@pytest.mark.parametrize(("experiment", "resolution"), [("quickstart", 256), ("table1", 256), ("paper", 512)])
def test_experiments_set_the_scene_where_generate_py_does(experiment: str, resolution: int) -> None:
    cfg = _compose("train", [f"experiment={experiment}", "scene.clutter=2"])
    scene = SceneConfig.from_dict(OmegaConf.to_container(cfg.data.generate, resolve=True)["scene"])
    assert (scene.resolution, scene.clutter) == (resolution, 2)


def test_the_old_address_set_apart_is_refused_naming_the_key() -> None:
    """``+data.generate.scene.camera_file=...`` would replace every scene setting (the resolution among
    them) while the data folder is still named after scene.resolution."""
    cfg = _compose("train", ["+data.generate.scene.camera_file=camera.yaml"])
    assert OmegaConf.to_container(cfg.data.generate)["scene"] == {"camera_file": "camera.yaml"}  # what Hydra made
    with pytest.raises(ValueError, match=r"write scene\.camera_file=\.\.\. instead of data\.generate\.scene"):
        check_scene_address(cfg)
