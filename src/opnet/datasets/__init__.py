"""Dataset records, readers and writers (Fraunhofer IPA and Siléane layouts)."""

from opnet.datasets.record import SceneRecord

__all__ = ["SceneRecord"]
