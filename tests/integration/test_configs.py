"""Every config composes, and every group option instantiates what it names; each entry config
(train, generate, eval, predict, export) holds what its command reads and resolves completely."""

from __future__ import annotations

import ast
import re
import shutil
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.utils import get_object, instantiate
from omegaconf import OmegaConf

from opnet.cli.build import build_components
from opnet.paths import REPO_ROOT, config_dir
from param_checks import parameterization_names

CONF = config_dir()
PARAMETERIZATIONS = parameterization_names()
BUILTIN_OBJECTS = ["bracket", "zbracket", "shaft", "pin"]


def _compose(name: str, overrides: list[str]) -> OmegaConf:
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return compose(config_name=name, overrides=overrides, return_hydra_config=False)


def test_the_papers_six_parameterizations_are_configured() -> None:
    assert set(PARAMETERIZATIONS) >= {"vanilla", "eve", "ap", "z", "mp", "si"}  # and any added since


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


#: the entry scripts at the top of the repository: config name -> the opnet.cli module whose run(cfg) it calls
ENTRIES = {m.group(1): re.search(r"from opnet\.cli\.(\w+) import run", text).group(1)
           for script in sorted(REPO_ROOT.glob("*.py"))
           if (m := re.search(r'@hydra\.main\(.*config_name="(\w+)"', text := script.read_text()))}  # fmt: skip
#: what each entry config leaves to the command line (``???``), with a value to give it
REQUIRED = {"train": {}, "generate": {}, "eval": {"ckpt": "x.ckpt"}, "predict": {"ckpt": "x.ckpt", "input": "in"},
            "export": {"ckpt": "x.ckpt"}}  # fmt: skip
#: keys a command reads with ``cfg.get`` that its config leaves out on purpose (given with ``+key=...``)
OPTIONAL = {"train": {"inference"}}
_ABSENT = object()


def cli_reads(source: Path) -> dict[str, int]:
    """The config keys a command module reads from ``cfg`` (``cfg.a.b``, ``cfg["a"]``,
    ``cfg.get("a")``, ``cfg.a.get("b")``), each with the first line that reads it."""
    reads: dict[str, int] = {}
    for node in ast.walk(ast.parse(source.read_text(), str(source))):
        chain: list[str] = []
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "get"
                and node.args and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)):
            chain, node = [node.args[0].value], node.func.value
        elif isinstance(node, ast.Subscript) and isinstance(node.slice, ast.Constant) and isinstance(node.slice.value, str):
            chain, node = [node.slice.value], node.value
        elif not isinstance(node, ast.Attribute):
            continue
        line = node.lineno
        while isinstance(node, ast.Attribute):
            chain.insert(0, node.attr)
            node = node.value
        while chain and chain[-1] in ("get", "items", "keys", "values", "pop", "copy"):
            chain.pop()  # a method of the node, not a key
        if isinstance(node, ast.Name) and node.id == "cfg" and chain:
            key = ".".join(chain)
            reads[key] = min(reads.get(key, line), line)
    return reads


def _targets(node: object, where: str = "") -> list[tuple[str, str]]:
    """(config key, ``_target_``) of every node of a resolved config that names one."""
    found: list[tuple[str, str]] = []
    if isinstance(node, dict):
        if isinstance(node.get("_target_"), str):
            found.append((where or "<root>", node["_target_"]))
        for k, v in node.items():
            found += _targets(v, f"{where}.{k}" if where else str(k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            found += _targets(v, f"{where}[{i}]")
    return found


def entry_config_problems(conf: Path, name: str, cli: Path, required: dict[str, str],
                          optional: frozenset[str] = frozenset()) -> list[str]:  # fmt: skip
    """What is wrong with the entry config ``conf/name.yaml`` for the command ``cli`` (empty: nothing):
    it must compose; leave exactly ``required`` to the command line; resolve completely once they are
    given (every interpolation, nothing missing); hold every key ``cli`` reads (but ``optional``); and
    every ``_target_`` in it must import."""
    paths = ["paths.root_dir=/tmp/opnet", "paths.output_dir=/tmp/opnet/run"]  # what the Hydra run gives
    try:
        with initialize_config_dir(config_dir=str(conf), version_base="1.3"):
            bare = compose(config_name=name, overrides=paths)
            cfg = compose(config_name=name, overrides=paths + [f"{k}={v}" for k, v in required.items()])
    except Exception as e:  # noqa: BLE001 - the failure is the finding
        return [f"conf/{name}.yaml does not compose: {type(e).__name__}: {e}"]
    problems = []
    try:
        if (missing := OmegaConf.missing_keys(bare)) != set(required):
            problems.append(f"conf/{name}.yaml leaves {sorted(missing)} to the command line, expected {sorted(required)}")
        resolved = OmegaConf.to_container(cfg, resolve=True, throw_on_missing=True)
    except Exception as e:  # noqa: BLE001
        return [*problems, f"conf/{name}.yaml does not resolve with {required}: {type(e).__name__}: {e}"]
    for key, line in sorted(cli_reads(cli).items()):
        if key not in optional and OmegaConf.select(cfg, key, default=_ABSENT) is _ABSENT:
            problems.append(f"{cli.name}:{line} reads cfg.{key}, which conf/{name}.yaml does not have")
    for key, target in _targets(resolved):
        try:
            get_object(target)
        except Exception as e:  # noqa: BLE001
            problems.append(f"conf/{name}.yaml {key}._target_={target} does not import: {type(e).__name__}: {e}")
    return problems


def test_every_entry_script_has_its_config_checked() -> None:
    assert set(ENTRIES) == set(REQUIRED), "a new entry script: say in REQUIRED what its config leaves to the command line"
    assert ENTRIES == {name: name for name in REQUIRED}  # each script found, with the command it runs


@pytest.mark.parametrize("name", sorted(REQUIRED))
def test_entry_configs_compose(name: str) -> None:
    cli = REPO_ROOT / "src" / "opnet" / "cli" / f"{ENTRIES[name]}.py"
    assert len(cli_reads(cli)) >= 5  # the command's reads were found
    assert entry_config_problems(CONF, name, cli, REQUIRED[name], frozenset(OPTIONAL.get(name, ()))) == []


def test_the_entry_config_check_fails_on_a_broken_config(tmp_path: Path) -> None:
    conf = shutil.copytree(CONF, tmp_path / "conf")
    cli = REPO_ROOT / "src" / "opnet" / "cli"

    def problems(name: str) -> list[str]:
        return entry_config_problems(conf, name, cli / f"{ENTRIES[name]}.py", REQUIRED[name],
                                     frozenset(OPTIONAL.get(name, ())))  # fmt: skip

    def edit(name: str, old: str, new: str) -> None:
        path = conf / name
        assert old in path.read_text()
        path.write_text(path.read_text().replace(old, new))

    assert problems("export") == [] and problems("train") == []  # the copy is sound
    edit("export.yaml", "format: onnx\n", "")  # a key the command reads, gone
    edit("export.yaml", "check: true", "verify: true")  # read with cfg.get("check", True): its default would hide it
    assert [p.split(", which")[0] for p in problems("export")] == [
        f"export.py:{cli_reads(cli / 'export.py')['check']} reads cfg.check",
        f"export.py:{cli_reads(cli / 'export.py')['format']} reads cfg.format"]  # fmt: skip
    edit("export.yaml", "ckpt: ???", "ckpt: null")  # the required field, no longer asked for
    assert "leaves [] to the command line, expected ['ckpt']" in problems("export")[0]
    edit("generate.yaml", "out: ${paths.data_dir}", "out: ${paths.no_such_dir}")  # an interpolation to nowhere
    assert "does not resolve" in problems("generate")[-1] and "no_such_dir" in problems("generate")[-1]
    edit("data/synthetic.yaml", "OPNetDataModule", "OPNetDataModul")  # a _target_ that is no object
    [found] = problems("train")
    assert found.startswith("conf/train.yaml data._target_=opnet.data.datamodule.OPNetDataModul does not import")
    edit("eval.yaml", "refine: model", "refine: nothing")  # an option that does not exist
    assert problems("eval")[0].startswith("conf/eval.yaml does not compose")


def test_slurm_launcher_config_names_submitit() -> None:
    text = (CONF / "hydra" / "launcher" / "slurm.yaml").read_text()
    assert "submitit_slurm" in text and "gpus_per_node" in text


@pytest.mark.parametrize("value", ["true", "abc", "4"])
def test_an_input_size_that_is_no_size_is_named(value: str) -> None:
    with pytest.raises(ValueError, match=r"data.input_size=.*expected a whole number of pixels"):
        build_components(_compose("train", [f"data.input_size={value}", "paths.root_dir=/tmp/opnet"]))
