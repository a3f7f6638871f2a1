"""Object models: mesh + symmetry + the metric's Λ, centroid and δ; the built-in library."""

from opnet.objects.config import object_from_config
from opnet.objects.io import load_mesh, load_object
from opnet.objects.library import builtin_names, builtin_object
from opnet.objects.model import ObjectModel

__all__ = ["ObjectModel", "builtin_names", "builtin_object", "object_from_config", "load_mesh", "load_object"]
