"""Pose refinement against the depth image: point-to-plane ICP and the depth-agreement search
(``refine=icp`` / ``refine=search``, conf/refine/). Numpy and scipy only, so that training's
evaluation, ``predict.py`` and the torch-free ONNX runtime (:mod:`opnet.deploy`) share it.

- :mod:`~opnet.refine.settings`: :class:`ICPSettings`, :class:`SearchSettings` and their making from
  the ``refine`` config group (the one reader of ``conf/refine/`` below the entry points);
- :mod:`~opnet.refine.clouds`: the model's and the scene's point clouds;
- :mod:`~opnet.refine.icp`: ICP of one pose (cost, step, guard);
- :mod:`~opnet.refine.associations`: ICP of many poses at once, nearest-point or projective;
- :mod:`~opnet.refine.agreement`: how well a depth image agrees with a pose;
- :mod:`~opnet.refine.search`: the search over the turns and shifts ICP cannot tell apart;
- :mod:`~opnet.refine.pipeline`: an image's hypotheses refined within a time budget
  (:func:`refine_image`, :class:`Refiner`).

Names are imported on first use (PEP 562).
"""

from __future__ import annotations

from opnet._lazy import lazy_exports

_WHERE = {
    "ASSOCIATIONS": "settings",
    "ICPSettings": "settings",
    "SearchSettings": "settings",
    "model_refinement": "settings",
    "refine_config": "settings",
    "search_settings": "settings",
    "settings_from_config": "settings",
    "ModelCloud": "clouds",
    "SceneCloud": "clouds",
    "STATUSES": "icp",
    "ICPResult": "icp",
    "refine_pose": "icp",
    "refine_poses_nearest": "associations",
    "refine_poses_projective": "associations",
    "STAGES": "pipeline",
    "Refiner": "pipeline",
    "rank_cloud": "pipeline",
    "refine_hypotheses": "pipeline",
    "refine_image": "pipeline",
    "serial_blas": "pipeline",
}
__getattr__, __dir__, __all__ = lazy_exports(__name__, _WHERE)
