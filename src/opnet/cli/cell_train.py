"""``train.py experiment=cell``: the cell as resolved, stated first, every measured key required, the data
folder named for the cell's values (:func:`state_cell`, called by ``train.py`` before the run)."""

from __future__ import annotations

import hashlib
import json
from typing import Any


def _given_on_command_line(key: str) -> bool:
    """Whether the Hydra command line set ``key`` (``key=...``, ``+key=...``, ``++key=...``)."""
    try:
        from hydra.core.hydra_config import HydraConfig

        overrides = HydraConfig.get().overrides.task
    except ValueError:  # composed without Hydra's runtime (a test's compose): no command line to ask
        return True
    return any(o.lstrip("+").split("=", 1)[0] == key for o in overrides)


def _planes(clip: Any) -> str:
    """``scene.clip`` as the console states it: ``near-far m`` where it gives metres."""
    if isinstance(clip, list | tuple) and len(clip) == 2:
        return f"{clip[0]}-{clip[1]} m"
    return f"{clip}"


def _old_spelling(cfg: Any, key: str) -> str:
    """For ``scene.clip``: the line to write where the config holds the working volume as an earlier opnet-cell
    wrote it (the keys a dataset records it with, read by :func:`opnet.synthesis.working_volume.from_recorded`);
    else ''."""
    from omegaconf import OmegaConf

    from opnet.synthesis.working_volume import RECORDED_KEYS, from_recorded

    scene = cfg.get("scene") if key == "scene.clip" else None
    old = {k: OmegaConf.select(scene, k) for k in RECORDED_KEYS if scene is not None and k in scene}
    if not old:
        return ""
    planes = from_recorded(old, "scene")["clip"]
    written = ", ".join("null" if plane is None else str(plane) for plane in planes)
    return (f"; the config sets {' and '.join(f'scene.{k}' for k in old)}, an earlier spelling: write clip: "
            f"[{written}] under scene instead (near and far plane, metres; an entry may be null: derived)")


def state_cell(cfg: Any) -> list[str]:
    """For ``experiment=cell`` (a config with a ``cell`` node): every measured key resolved (the first one
    missing is a ValueError naming it and where to get it), a sensor preset chosen by the cell file or the
    command line, ``cell.tag`` set to a digest of the cell's values (the data folder follows them: a
    re-measured cell gets new piles), and the console's lines stating the cell. Other configs: nothing."""
    from omegaconf import OmegaConf
    from omegaconf.errors import MissingMandatoryValue

    from opnet.cell.cellfile import MEASURED_KEYS

    if "cell" not in cfg:
        return []
    name = cfg.cell.get("name")
    values = {}
    for key in MEASURED_KEYS:
        try:
            value = OmegaConf.select(cfg, key, throw_on_missing=True)
        except MissingMandatoryValue:
            value = None
        if value is None:
            where = f"conf/cell/{name}.yaml lacks it" if name else "give cell=<name> (a cell file of opnet-cell)"
            raise ValueError(f"experiment=cell: {key} is not set ({where}, or {key}=<value>){_old_spelling(cfg, key)}")
        values[key] = OmegaConf.to_container(value) if OmegaConf.is_config(value) else value
    sensor = cfg.sensor.get("name", "ideal")
    if not cfg.cell.get("sensor") and not _given_on_command_line("sensor"):
        raise ValueError(f"experiment=cell: no sensor preset: {'the cell file names none' if name else 'no cell file'}; "
                         f"give sensor=<preset> (conf/sensor/; opnet-cell check compares them with your frames)")
    digest = hashlib.sha256(json.dumps({**values, "sensor": sensor}, sort_keys=True, default=str).encode()).hexdigest()
    cfg.cell.tag = f"{name or 'given'}_{digest[:8]}"
    s = {k.split(".", 1)[1]: v for k, v in values.items()}
    lines = [f"cell {name or '(from the command line)'}: camera {s['camera_file']} at {s['camera_height']} m over the bin "
             f"floor, tilt {s['camera_tilt_deg']} deg, azimuth {s['camera_azimuth_deg']} deg; working volume "
             f"{_planes(s['clip'])}, area {s['bin_area']} m",
             f"  bin {s['bin_inner']} x {s['bin_inner_y']} m, walls {s['bin_wall_height']} m (thickness "
             f"{s['bin_wall_thickness']} m), {s['bin_clearance']} m over the ground; crop {s['roi']}; sensor {sensor}; "
             f"data {cfg.data.root}"]
    return lines
