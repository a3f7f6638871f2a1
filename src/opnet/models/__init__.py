"""Backbones (plain ``nn.Module``s, configured from ``conf/model``): the DenseNet-BC of OP-Net."""

from opnet.models.densenet import DenseNetBC

__all__ = ["DenseNetBC"]
