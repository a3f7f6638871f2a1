"""opnet: single-shot 6D object pose estimation from depth images (OP-Net and its output
parameterizations, Kleeberger et al., ICRA 2021)."""

__version__ = "0.1.0"
