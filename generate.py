"""Generate synthetic bin-picking scenes: ``python generate.py object=bunny cycles=100 drops=20 workers=2``.

See conf/generate.yaml; the logic lives in :func:`opnet.cli.generate.run`.
"""

import os

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import hydra  # noqa: E402
from omegaconf import DictConfig  # noqa: E402


@hydra.main(config_path="conf", config_name="generate", version_base="1.3")
def main(cfg: DictConfig) -> None:
    from opnet.cli.console import guarded
    from opnet.cli.generate import run

    guarded(run, cfg)  # a user error: one line naming the file or key, exit 2


if __name__ == "__main__":
    main()
