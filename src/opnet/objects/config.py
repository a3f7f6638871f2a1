"""Object models from Hydra object configs (``conf/object/<name>.yaml``)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from opnet._repr import short_repr
from opnet.geometry.symmetry import Symmetry
from opnet.objects.bop import bop_id, bop_object
from opnet.objects.io import load_object
from opnet.objects.model import ObjectModel

_KEYS = {"name", "builtin", "mesh", "mesh_scale", "symmetry", "model_rotation", "model_origin", "poseutils",
         "bop_models", "bop_obj_id"}


def object_from_config(cfg: Mapping[str, Any]) -> ObjectModel:
    """Build an object model from an object config mapping (a DictConfig or a plain dict)."""
    cfg = dict(cfg)
    unknown = set(cfg) - _KEYS
    if unknown:
        raise ValueError(f"object config: unknown keys {sorted(unknown)}; expected some of {sorted(_KEYS)}")
    if "name" not in cfg:
        raise ValueError("object config: missing key 'name'")
    if cfg.get("bop_models") is not None:  # a BOP model: mesh in mm and symmetries from models_info.json
        if cfg.get("bop_obj_id") is None:
            raise ValueError("object config: 'bop_models' needs 'bop_obj_id' (the BOP obj_id)")
        obj_id = bop_id(cfg["bop_obj_id"], "object.bop_obj_id", f"object {short_repr(cfg['name'])}")
        return bop_object(cfg["bop_models"], obj_id, str(cfg["name"]))
    symmetry = cfg.get("symmetry")
    if symmetry is not None and not isinstance(symmetry, str):
        if not isinstance(symmetry, Mapping):  # `symmetry: [revolution]`
            raise ValueError(f"object.symmetry of {short_repr(cfg['name'])}: expected a name (none, revolution, "
                             f"cyclic<N>) or a mapping with 'kind', got a {type(symmetry).__name__} "
                             f"{short_repr(symmetry)}")
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
        mesh_scale=_mesh_scale(cfg.get("mesh_scale", 1.0), cfg["name"]),
        model_rotation=cfg.get("model_rotation"),
        model_origin=cfg.get("model_origin") if isinstance(cfg.get("model_origin"), str | type(None)) else list(cfg["model_origin"]),
        builtin=cfg.get("builtin"),
        poseutils=cfg.get("poseutils"),
    )


def _mesh_scale(value: Any, name: Any) -> float:
    """``object.mesh_scale`` as a positive finite number (metres per mesh unit)."""
    scale = value if isinstance(value, int | float) and not isinstance(value, bool) else math.nan
    if not (math.isfinite(scale) and scale > 0):
        raise ValueError(f"object.mesh_scale={short_repr(value)} of {short_repr(name)}: expected a positive number "
                         "(metres per mesh unit: 0.001 for a mesh in millimetres)")
    return float(scale)
