"""Estimate poses: ``python predict.py ckpt=<path> input=<file or folder> out=<dir>``."""

import os
import sys

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import hydra  # noqa: E402
from omegaconf import DictConfig  # noqa: E402


@hydra.main(config_path="conf", config_name="predict", version_base="1.3")
def main(cfg: DictConfig) -> None:
    from opnet.cli.console import guarded
    from opnet.cli.predict import run

    failed = guarded(run, cfg)  # a user error: one line naming the file or key, exit 2
    if failed:  # some images of a folder failed (each named on its line)
        sys.exit(1)


if __name__ == "__main__":
    main()
