"""Train OP-Net: ``python train.py parameterization=eve object=shaft`` (see conf/train.yaml)."""

import os

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import hydra  # noqa: E402
from omegaconf import DictConfig  # noqa: E402


@hydra.main(config_path="conf", config_name="train", version_base="1.3")
def main(cfg: DictConfig) -> float | None:
    from opnet.cli.cell_train import state_cell
    from opnet.cli.console import guarded, report
    from opnet.cli.train import run

    def train(cfg: DictConfig) -> dict:
        if lines := state_cell(cfg):  # experiment=cell: the cell as resolved first (a missing key stops here)
            report(lines)
        return run(cfg)

    result = guarded(train, cfg)  # a user error: one line naming the file or key, exit 2
    return result.get("ap")  # the value an optimizing sweeper would maximize


if __name__ == "__main__":
    main()
