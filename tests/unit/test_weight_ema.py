"""The exponential moving average of the weights (opnet.callbacks.WeightEMA): the average it keeps,
what validation and checkpoints see, and a resume."""

from __future__ import annotations

import lightning as L
import pytest
import torch
from torch import nn

from opnet.callbacks import WeightEMA


class Toy(L.LightningModule):
    """A linear layer and a BatchNorm (buffers are averaged too); records the weight validation saw."""

    def __init__(self) -> None:
        super().__init__()
        self.lin = nn.Linear(3, 1)
        self.bn = nn.BatchNorm1d(3)
        self.seen: list[torch.Tensor] = []
        self.history: list[dict[str, torch.Tensor]] = []

    def training_step(self, batch, batch_idx):
        x, y = batch
        return ((self.lin(self.bn(x)) - y) ** 2).mean()

    def on_train_batch_end(self, outputs, batch, batch_idx):
        self.history.append({k: v.detach().clone() for k, v in self.state_dict().items() if v.is_floating_point()})

    def validation_step(self, batch, batch_idx):
        if batch_idx == 0:
            self.seen.append(self.lin.weight.detach().clone())

    def configure_optimizers(self):
        return torch.optim.SGD(self.parameters(), lr=0.05)


def loader(n: int = 8) -> torch.utils.data.DataLoader:
    g = torch.Generator().manual_seed(0)
    x = torch.randn(n * 4, 3, generator=g)
    return torch.utils.data.DataLoader(list(zip(x, x.sum(1, keepdim=True))), batch_size=4)


def trainer(tmp_path, ema: WeightEMA, steps: int) -> L.Trainer:
    return L.Trainer(max_steps=steps, callbacks=[ema], logger=False, enable_progress_bar=False,
                     enable_model_summary=False, default_root_dir=tmp_path, limit_val_batches=1,
                     val_check_interval=steps, enable_checkpointing=False)  # fmt: skip


def manual_average(start: dict[str, torch.Tensor], history: list[dict[str, torch.Tensor]], decay: float):
    avg = {k: v.clone() for k, v in start.items()}
    for n, state in enumerate(history):
        d = min(decay, (1 + n) / (10 + n))
        for k in avg:
            avg[k] = d * avg[k] + (1 - d) * state[k]
    return avg


def test_the_average_is_the_formula_and_validation_sees_it_then_training_weights_come_back(tmp_path):
    torch.manual_seed(0)
    model = Toy()
    start = {k: v.detach().clone() for k, v in model.state_dict().items() if v.is_floating_point()}
    ema = WeightEMA(decay=0.9)
    t = trainer(tmp_path, ema, steps=8)
    # validation after the last step, before on_train_end copies the average in
    t.fit(model, loader(), loader())
    expected = manual_average(start, model.history, 0.9)
    assert ema.updates == 8
    torch.testing.assert_close(model.seen[-1], expected["lin.weight"])
    # after fitting the module holds the average (what the best checkpoint and the test use)
    for k, v in expected.items():
        torch.testing.assert_close(model.state_dict()[k].float(), v, msg=k)
    assert not torch.allclose(expected["lin.weight"], model.history[-1]["lin.weight"])  # a real average


def test_a_checkpoint_holds_the_average_as_its_weights_and_a_resume_gets_the_training_weights(tmp_path):
    torch.manual_seed(0)
    model = Toy()
    ema = WeightEMA(decay=0.9)
    t = L.Trainer(max_steps=5, callbacks=[ema], logger=False, enable_progress_bar=False, enable_model_summary=False,
                  default_root_dir=tmp_path, limit_val_batches=0, enable_checkpointing=False)  # fmt: skip
    t.fit(model, loader())
    raw = model.history[-1]
    path = tmp_path / "a.ckpt"
    t.save_checkpoint(path)  # after fit: the module holds the average (swapped)
    ckpt = torch.load(path, weights_only=True)
    torch.testing.assert_close(ckpt["state_dict"]["lin.weight"], model.lin.weight.detach())
    torch.testing.assert_close(ckpt[WeightEMA.KEY]["raw"]["lin.weight"], raw["lin.weight"])
    assert ckpt[WeightEMA.KEY]["updates"] == 5

    resumed, ema2 = Toy(), WeightEMA(decay=0.9)
    seen: dict[str, torch.Tensor] = {}

    class Peek(L.Callback):
        def on_train_start(self, trainer, pl_module):
            seen["weight"] = pl_module.lin.weight.detach().clone()

    t2 = L.Trainer(max_steps=6, callbacks=[ema2, Peek()], logger=False, enable_progress_bar=False,
                   enable_model_summary=False, default_root_dir=tmp_path, limit_val_batches=0,
                   enable_checkpointing=False)  # fmt: skip
    t2.fit(resumed, loader(), ckpt_path=path, weights_only=True)
    torch.testing.assert_close(seen["weight"], raw["lin.weight"])  # training goes on from its own weights
    assert ema2.updates == 6


def test_decay_zero_is_off_and_bad_decays_are_one_line_errors(tmp_path):
    torch.manual_seed(0)
    model = Toy()
    ema = WeightEMA(decay=0.0)
    trainer(tmp_path, ema, steps=3).fit(model, loader(), loader())
    assert ema.average is None and ema.updates == 0
    torch.testing.assert_close(model.seen[-1], model.history[-1]["lin.weight"])
    for bad in (1.0, -0.1, True, "0.9"):
        with pytest.raises(ValueError, match=r"callbacks\.weight_ema\.decay"):
            WeightEMA(decay=bad)  # type: ignore[arg-type]
