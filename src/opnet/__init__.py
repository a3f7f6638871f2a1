"""opnet: single-shot 6D object pose estimation from depth images (OP-Net and its output
parameterizations, Kleeberger et al., ICRA 2021)."""

__version__ = "0.1.0"

import logging as _logging
import os as _os

# albumentations asks PyPI for its newest version when it is imported (its __init__ calls
# albumentations.check_version.check_for_updates unless NO_ALBUMENTATIONS_UPDATE is set). opnet never
# goes on the network: the check is turned off here, before any opnet module imports albumentations
# (a value the user set is kept).
_os.environ.setdefault("NO_ALBUMENTATIONS_UPDATE", "1")

# PyOpenGL announces at INFO that its optional C accelerator is absent, in every process that renders
_logging.getLogger("OpenGL.acceleratesupport").setLevel(_logging.WARNING)
