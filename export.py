"""Export a trained model: ``python export.py ckpt=<path> [format=onnx] [out=<file>]``."""

import os

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import hydra  # noqa: E402
from omegaconf import DictConfig  # noqa: E402


@hydra.main(config_path="conf", config_name="export", version_base="1.3")
def main(cfg: DictConfig) -> None:
    from opnet.cli.console import guarded
    from opnet.cli.export import run

    guarded(run, cfg)  # a user error: one line naming the file or key, exit 2


if __name__ == "__main__":
    main()
