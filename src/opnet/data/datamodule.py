"""The data module as a LightningDataModule: what train.py's Trainer runs (the configs' ``_target_``).

All of it is :class:`opnet.data.scene_data.SceneData`, which needs no Lightning: eval.py and the tools
that only read scenes build that one and start without loading Lightning.
"""

from __future__ import annotations

import lightning as L

from opnet.data.scene_data import SceneData


class OPNetDataModule(SceneData, L.LightningDataModule):
    """:class:`~opnet.data.scene_data.SceneData` with Lightning's hooks: ``trainer.fit`` calls its
    ``prepare_data`` (generation on first use), ``setup`` and the loaders."""
