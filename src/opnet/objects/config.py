"""Object models from Hydra object configs (``conf/object/<name>.yaml``)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from opnet.geometry.symmetry import Symmetry
from opnet.objects.io import load_object
from opnet.objects.model import ObjectModel

_KEYS = {"name", "builtin", "mesh", "mesh_scale", "symmetry", "model_rotation", "poseutils", "bop_models", "bop_obj_id"}


def object_from_config(cfg: Mapping[str, Any]) -> ObjectModel:
    """Build an object model from an object config mapping (a DictConfig or a plain dict)."""
    cfg = dict(cfg)
    unknown = set(cfg) - _KEYS
    if unknown:
        raise ValueError(f"object config: unknown keys {sorted(unknown)}; expected some of {sorted(_KEYS)}")
    if "name" not in cfg:
        raise ValueError("object config: missing key 'name'")
    if cfg.get("bop_models") is not None:  # a BOP model: mesh in mm and symmetries from models_info.json
        from opnet.datasets.bop import bop_object

        if cfg.get("bop_obj_id") is None:
            raise ValueError("object config: 'bop_models' needs 'bop_obj_id' (the BOP obj_id)")
        return bop_object(cfg["bop_models"], int(cfg["bop_obj_id"]), str(cfg["name"]))
    symmetry = cfg.get("symmetry")
    if symmetry is not None and not isinstance(symmetry, str):
        symmetry = {k: (list(v) if k == "rotations" else v) for k, v in dict(symmetry).items()}
    if symmetry is not None:
        try:  # checked here so that the message names the config key
            Symmetry.from_spec(symmetry)
        except ValueError as e:
            raise ValueError(f"object.symmetry of {cfg['name']!r}: {e}") from None
    return load_object(
        str(cfg["name"]),
        mesh=cfg.get("mesh"),
        symmetry=symmetry,
        mesh_scale=float(cfg.get("mesh_scale", 1.0)),
        model_rotation=cfg.get("model_rotation"),
        builtin=cfg.get("builtin"),
        poseutils=cfg.get("poseutils"),
    )
