"""opnet: single-shot 6D object pose estimation from depth images (OP-Net and its output
parameterizations, Kleeberger et al., ICRA 2021)."""

__version__ = "0.1.0"

import logging as _logging

# PyOpenGL announces at INFO that its optional C accelerator is absent, in every process that renders
_logging.getLogger("OpenGL.acceleratesupport").setLevel(_logging.WARNING)
