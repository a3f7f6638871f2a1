"""A parameterization added from outside the package, in the two files docs/extending.md asks for
(its class and its YAML), runs through what the six configured ones do: the encode / decode
contract, a training step, the ONNX export, and the fixed-shape decoding of the CUDA graph.

The seventh writes its depth channel reversed (1 at the near clip plane), so only its own
``decode_position`` reads its targets back, and orders its channels ``[v, rotation..., x, y, z, p]``,
so code that reads a channel anywhere but where ``layout`` says gets another quantity: a base class
that skips a hook, or a reader that slices channels by hand, fails here.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from pathlib import Path

import hydra.utils
import lightning as L
import pytest
import torch
from omegaconf import OmegaConf

from conftest import compose_cfg
from opnet.analysis.toy_scenes import random_scene_batch
from opnet.cli.build import build_components
from opnet.data.preprocess import network_camera
from opnet.data.sample import Batch
from opnet.geometry import Camera
from opnet.objects import builtin_object
from opnet.parameterizations.base import ChannelLayout
from opnet.parameterizations.dense_decoding import DenseDecoding
from param_checks import (
    assert_export_matches,
    assert_graph_capturable,
    assert_round_trip,
    assert_same_hypotheses,
    noisy_outputs,
    parameterization_names,
    tiny_system,
)

MODULE = "opnet_seventh_example"
CLASS = '''
import torch

from opnet.parameterizations.assignment import Candidates, flat_cell
from opnet.parameterizations.base import ChannelLayout, Parameterization
from opnet.parameterizations.positions import cell_pixel


class SeventhParameterization(Parameterization):
    """Vanilla's cells, the depth channel reversed (1 - normalized depth), the channels reordered."""

    def __init__(self, obj, grid=16, **kwargs):
        super().__init__(obj, grid, **kwargs)
        c = self.layout.channels
        self.layout = ChannelLayout(presence=c - 1, visibility=0, position=slice(c - 4, c - 1),
                                    rotation=slice(1, c - 4), channels=c)

    def candidates(self, gt, proj):
        cells = proj.cells(self.grid_size)
        idx = torch.nonzero(cells.inside & proj.in_range)[:, 0]
        cell = flat_cell(gt.batch_index[idx], 0, cells.row[idx], cells.col[idx], self.slots, self.grid_size)
        position = torch.stack((cells.x, cells.y, 1 - proj.z_norm), -1)[idx]
        return Candidates(idx, cell, gt.visibility[idx].double(), position)

    def decode_position(self, position, cells, cams):
        _, row, col = cells
        u, v = cell_pixel(row, col, position[:, 0], position[:, 1], cams, self.grid_size)
        return u, v, 1 - position[:, 2]
'''
YAML = f"""\
_target_: {MODULE}.SeventhParameterization
_convert_: object
grid: 16
threshold: 0.1
score: p
min_visibility: 0.0
min_target_visibility: 0.0
averaging: false
"""
CAMERA = network_camera(Camera.from_fov(50.0, 512, 512, 0.6, 1.2))


@pytest.fixture(scope="module")
def conf(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """A config folder holding ``parameterization/seventh.yaml``, its class importable."""
    root = tmp_path_factory.mktemp("seventh")
    (root / f"{MODULE}.py").write_text(CLASS)
    (root / "conf" / "parameterization").mkdir(parents=True)
    (root / "conf" / "parameterization" / "seventh.yaml").write_text(YAML)
    with pytest.MonkeyPatch.context() as mp:
        mp.syspath_prepend(str(root))
        yield root / "conf"
    sys.modules.pop(MODULE, None)


def _overrides(conf: Path, *extra: str) -> list[str]:
    return [f"hydra.searchpath=[file://{conf}]", "parameterization=seventh", *extra]


@pytest.mark.parametrize(("name", "rotation"), [("zbracket", "r6d"), ("pin", "euler_zyz")])  # 8 and 7 channels
def test_the_seventh_keeps_the_encode_decode_contract(conf: Path, name: str, rotation: str) -> None:
    assert parameterization_names(conf) == ["seventh"]
    obj = builtin_object(name)
    codec = hydra.utils.instantiate(compose_cfg("train", [f"rotation={rotation}"]).rotation, _partial_=True)
    param = hydra.utils.instantiate(OmegaConf.load(conf / "parameterization" / "seventh.yaml"), obj=obj,
                                    rotation=codec(symmetry=obj.symmetry))  # fmt: skip
    c = 5 + codec(symmetry=obj.symmetry).num_channels
    assert param.layout == ChannelLayout(c - 1, 0, slice(c - 4, c - 1), slice(1, c - 4), c)
    assert param.name == "seventh" and param.channel_layout()[0] == "v" and param.channel_layout()[-4:] == list("xyzp")
    gt = random_scene_batch(obj, CAMERA, 3, 25, torch.Generator().manual_seed(1))
    assert_round_trip(param, gt, CAMERA)


@pytest.mark.parametrize("formulation", ["ours", "paper"])
def test_the_seventh_trains_a_step(conf: Path, formulation: str) -> None:
    cfg = compose_cfg("train", _overrides(conf, "model=tiny", f"formulation={formulation}"))
    system = build_components(cfg).system
    param = system.parameterization
    gt = random_scene_batch(param.obj, CAMERA, 2, 20, torch.Generator().manual_seed(0))
    images = torch.rand(2, 1, 128, 128, generator=torch.Generator().manual_seed(0))
    batch = Batch(images, [CAMERA] * 2, gt, [], ["a", "b"])
    before = [p.detach().clone() for p in system.parameters()]
    L.seed_everything(0)
    trainer = L.Trainer(accelerator="cpu", max_steps=1, limit_val_batches=0, logger=False, enable_checkpointing=False,
                        enable_progress_bar=False, enable_model_summary=False)  # fmt: skip
    trainer.fit(system, train_dataloaders=torch.utils.data.DataLoader([batch], collate_fn=lambda b: b[0]))
    assert trainer.global_step == 1
    assert any(not torch.equal(a, b.detach()) for a, b in zip(before, system.parameters(), strict=True))
    # each term reads its own channels: a target moved in its position (rotation) channels costs position (orientation) only
    target = param.encode(gt, CAMERA)
    present = param.split_slots(target)[:, :, param.layout.presence] > 0
    for moved, term in ((param.layout.position, "position"), (param.layout.rotation, "orientation")):
        output = param.split_slots(target.clone())
        output[:, :, moved] = (output[:, :, moved] + 0.1 * present[:, :, None]).clamp(0, 1)
        losses = system.loss(output.reshape(target.shape), target, param, [CAMERA] * 2)
        assert {k for k, v in losses.items() if v > 1e-6} == {term, "total"}, (term, losses)  # 1e-13: re-encoding


def test_the_seventh_exports_to_onnx(conf: Path, tmp_path: Path) -> None:
    pytest.importorskip("onnxruntime")
    cfg = compose_cfg("train", _overrides(conf, "model=tiny", "object=zbracket"))
    system = build_components(cfg).system.eval()
    assert assert_export_matches(system, cfg, tmp_path / "seventh.onnx")["parameterization"] == "seventh"


def test_the_seventh_decodes_with_fixed_shapes(conf: Path) -> None:
    """The dense decoding of the CUDA graph (here on the CPU) gives the host's hypotheses, with and
    without averaging, the averaging on the device too; on the meta device nothing is read back."""
    system = tiny_system(_overrides(conf, "decoding=tuned"))
    for averaging in (False, {"eps": 1.5, "cluster_score": "sum"}):
        param = system.parameterization.with_decoding(averaging=averaging, score="p*v")
        out = noisy_outputs(param, CAMERA, 6, seed=3)
        host = param.decode(out, CAMERA)
        assert sum(len(h) for h in host) > 20
        assert_same_hypotheses(host, DenseDecoding(param, CAMERA, 6, "cpu").decode(out))
        assert_same_hypotheses(host, param.decode(out, CAMERA, device_side=True))
    assert_graph_capturable(system)
