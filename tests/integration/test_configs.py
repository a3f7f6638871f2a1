"""Every config composes, and every group option instantiates what it names."""

from __future__ import annotations

import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate
from omegaconf import OmegaConf

from opnet.cli.build import build_components
from opnet.paths import config_dir

CONF = config_dir()
PARAMETERIZATIONS = sorted(p.stem for p in (CONF / "parameterization").glob("*.yaml"))
BUILTIN_OBJECTS = ["bracket", "zbracket", "shaft", "pin"]


def _compose(name: str, overrides: list[str]) -> OmegaConf:
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return compose(config_name=name, overrides=overrides, return_hydra_config=False)


def test_all_six_parameterizations_are_configured() -> None:
    assert set(PARAMETERIZATIONS) == {"vanilla", "eve", "ap", "z", "mp", "si"}


@pytest.mark.parametrize("parameterization", PARAMETERIZATIONS)
def test_train_config_builds_every_parameterization(parameterization: str) -> None:
    cfg = _compose("train", [f"parameterization={parameterization}", "model=tiny", "paths.root_dir=/tmp/opnet"])
    comps = build_components(cfg)
    p = comps.parameterization
    # the network's output grid and channels follow the parameterization
    assert p.grid_size == cfg.parameterization.grid
    head_out = [m for m in comps.system.backbone.modules() if hasattr(m, "out_channels")][-1].out_channels
    assert head_out == p.out_channels


def test_a_larger_input_needs_the_network_built_for_it() -> None:
    # fed 256 pixels, a network built for 128 puts out a 32 x 32 grid against the parameterization's 16: refused
    # before training, naming the keys and both ways out
    with pytest.raises(ValueError, match=r"data.input_size=256 but model.in_size=128: .* set model.in_size=256 with "
                                         r"parameterization.grid=32 .*or alone"):  # fmt: skip
        build_components(_compose("train", ["parameterization=eve", "data.input_size=256", "paths.root_dir=/tmp/opnet"]))
    for extra in (["parameterization.grid=32"], []):  # the same network at twice the input, or one halving more
        cfg = _compose("train", ["parameterization=eve", "data.input_size=256", "model.in_size=256", *extra,
                                 "paths.root_dir=/tmp/opnet"])  # fmt: skip
        system = build_components(cfg).system
        out = system.backbone(torch.zeros(1, 1, 256, 256))
        assert out.shape[-1] == cfg.parameterization.grid


@pytest.mark.parametrize("obj", BUILTIN_OBJECTS)
def test_train_config_every_builtin_object(obj: str) -> None:
    cfg = _compose("train", [f"object={obj}", "paths.root_dir=/tmp/opnet"])
    assert build_components(cfg).obj.name == obj


@pytest.mark.parametrize("group", ["model", "loss", "augmentation", "rotation"])
def test_group_options_instantiate(group: str) -> None:
    from opnet.geometry import Symmetry

    for option in sorted((CONF / group).glob("*.yaml")):
        cfg = _compose("train", [f"{group}={option.stem}", "paths.root_dir=/tmp/opnet"])[group]
        if group == "model":
            assert instantiate(cfg, out_channels=8, out_grid=16) is not None
        elif group == "rotation":
            assert instantiate(cfg, _partial_=True)(symmetry=Symmetry("cyclic", order=2)).num_channels > 0
        elif cfg is not None and len(cfg):
            instantiate(cfg)


def test_formulations_select_the_paper_or_our_measured_best() -> None:
    ours = _compose("train", ["parameterization=eve", "paths.root_dir=/tmp/opnet"])
    paper = _compose("train", ["parameterization=eve", "formulation=paper", "paths.root_dir=/tmp/opnet"])
    assert (ours.rotation._target_.endswith("SixDCodec"), ours.loss.orientation, ours.parameterization.position) == (
        True, "sym_channel_l2", "cell_offset")
    assert (paper.rotation.convention, paper.loss.orientation, paper.loss.position, paper.parameterization.position,
            paper.parameterization.score, paper.parameterization.averaging_eps) == (
        "ZYZ", "euler_l2", "channels", "enlarged", "p", 0.5)  # fmt: skip
    # a command-line choice still wins over the formulation's
    mixed = _compose("train", ["formulation=paper", "loss=balanced", "paths.root_dir=/tmp/opnet"])
    assert mixed.loss.orientation == "sym_channel_l2" and mixed.rotation.convention == "ZYZ"
    vanilla_paper = _compose("train", ["formulation=paper", "paths.root_dir=/tmp/opnet"])
    assert vanilla_paper.parameterization.averaging is False  # the paper's vanilla does not average


def test_bad_learning_settings_name_their_config_key() -> None:
    from hydra.errors import InstantiationException, MissingConfigException

    bad = (ValueError, InstantiationException)  # hydra wraps what the class raises, message included
    with pytest.raises(MissingConfigException, match="rotation"):
        _compose("train", ["rotation=quaternion"])
    with pytest.raises(bad, match=r"rotation.convention='ZYX'"):
        build_components(_compose("train", ["object=zbracket", "rotation=euler_zyz", "rotation.convention=ZYX",
                                            "paths.root_dir=/tmp/opnet"]))  # fmt: skip
    with pytest.raises(bad, match="parameterization.averaging_eps"):
        build_components(_compose("train", ["parameterization.averaging_eps=-0.5", "paths.root_dir=/tmp/opnet"]))
    with pytest.raises(bad, match="loss.position"):
        build_components(_compose("train", ["loss.position=pixels", "paths.root_dir=/tmp/opnet"]))
    with pytest.raises(bad, match="parameterization.position"):
        build_components(_compose("train", ["parameterization=ap", "multi_cell_position=image",
                                            "paths.root_dir=/tmp/opnet"]))  # fmt: skip


@pytest.mark.parametrize("experiment", sorted(p.stem for p in (CONF / "experiment").glob("*.yaml")))
def test_experiments_compose(experiment: str) -> None:
    cfg = _compose("train", [f"experiment={experiment}", "paths.root_dir=/tmp/opnet"])
    assert cfg.task_name == experiment
    assert cfg.data.generate is not None


def test_dense_recipe_is_the_measured_best_and_builds() -> None:
    """experiment=dense trains what results/dense/ab_learning.md measured best on dense piles: EVE with
    the depth channel weighted 10x; the loss built from it carries that weight."""
    cfg = _compose("train", ["experiment=dense", "object=shaft", "paths.root_dir=/tmp/opnet"])
    assert cfg.parameterization._target_.endswith("EVEParameterization")
    assert cfg.loss.lambda_z == 10.0
    assert build_components(cfg).system.loss.lambda_z == 10.0


@pytest.mark.parametrize("trainer", ["cpu", "gpu", "ddp"])
def test_trainer_configs_compose(trainer: str) -> None:
    cfg = _compose("train", [f"trainer={trainer}", "paths.root_dir=/tmp/opnet"])
    assert cfg.trainer._target_ == "lightning.pytorch.Trainer"


@pytest.mark.parametrize("name", ["eval", "predict", "generate"])
def test_entry_configs_compose(name: str) -> None:
    if not (CONF / f"{name}.yaml").exists():
        pytest.skip(f"conf/{name}.yaml not present")
    cfg = _compose(name, ["paths.root_dir=/tmp/opnet"] + (["ckpt=x"] if name in ("eval", "predict") else []))
    assert cfg is not None


def test_slurm_launcher_config_names_submitit() -> None:
    text = (CONF / "hydra" / "launcher" / "slurm.yaml").read_text()
    assert "submitit_slurm" in text and "gpus_per_node" in text


@pytest.mark.parametrize("value", ["true", "abc", "4"])
def test_an_input_size_that_is_no_size_is_named(value: str) -> None:
    with pytest.raises(ValueError, match=r"data.input_size=.*expected a whole number of pixels"):
        build_components(_compose("train", [f"data.input_size={value}", "paths.root_dir=/tmp/opnet"]))
