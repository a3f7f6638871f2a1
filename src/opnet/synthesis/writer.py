"""Generated datasets on disk: the IPA layout (docs/formats.md#fraunhofer-ipa-layout) plus our own root files.

```
<root>/parameter.json          IPA camera and drop settings (opnet.datasets.ipa_params)
<root>/object.json             the object config (keys of conf/object/*.yaml): object_from_config rebuilds it
<root>/poseutils.json          the official Siléane pose-utils of the object (ObjectModel.to_poseutils)
<root>/generation.json         seed, drops and scene settings: a resumed run must match them
<root>/gt|p_depth|p_segmentation/cycle_XXXX/...   scenes, via opnet.datasets.ipa.write_ipa_scene
<root>/gt/cycle_XXXX/bin_model.json              with scene.bin_models: the pile's bin model and its bin
<root>/preview/cycle_XXXX_NNN.png                 depth | segmentation, for a few scenes
```
A cycle is complete when the CSVs of all its scenes 000..drops exist (each scene writes its CSV
last, and the scenes are written in order). An incomplete cycle is deleted and made again.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from opnet.datasets.ipa import scene_paths, write_ipa_scene
from opnet.datasets.ipa_params import IPAParameters, write_parameters
from opnet.fileio.atomic import disk_full_named, write_text_atomic, write_text_if_changed
from opnet.objects.library import BUILTINS, builtin_object
from opnet.objects.model import ObjectModel
from opnet.synthesis.config import MAX_SCENE_M, SceneConfig
from opnet.synthesis.layout import totes
from opnet.synthesis.preview import write_preview
from opnet.synthesis.sensor import SensorModel
from opnet.synthesis.working_volume import normal_recorded

if TYPE_CHECKING:  # the generator (pybullet, pyrender) is not needed to read or check a dataset
    from opnet.synthesis.cycle import CycleResult

OBJECT_FILE = "object.json"
POSEUTILS_FILE = "poseutils.json"
GENERATION_FILE = "generation.json"
PREVIEW_DIR = "preview"
MESH_COPY = "object_mesh.ply"
BIN_MODEL_FILE = "bin_model.json"
_SCENE_DIRS = ("gt", "p_depth", "p_segmentation")
_FORMAT = 1


def _json_text(data: Any) -> str:
    return json.dumps(data, indent=2, sort_keys=True) + "\n"


def object_config_for(obj: ObjectModel, root: Path) -> dict[str, Any]:
    """An object config that rebuilds ``obj``: the built-in's name, or a mesh copy in ``root``."""
    if obj.name in BUILTINS and obj.mesh is not None and np.array_equal(obj.mesh.vertices, builtin_object(obj.name).mesh.vertices):
        return {"name": obj.name, "builtin": obj.name}
    if obj.mesh is None:
        raise ValueError(f"object {obj.name!r} has no mesh: the generator needs one to simulate and render")
    path = (root / MESH_COPY).resolve()
    with disk_full_named(path):
        root.mkdir(parents=True, exist_ok=True)
        obj.mesh.export(path)
    return {"name": obj.name, "mesh": str(path), "mesh_scale": 1.0, "symmetry": obj.symmetry.to_spec()}


def normalized_object_config(config: Mapping[str, Any]) -> dict[str, Any]:
    """Plain-data copy of an object config, with a relative mesh path made absolute."""
    out = json.loads(json.dumps(dict(config), default=lambda o: dict(o) if isinstance(o, Mapping) else list(o)))
    if out.get("mesh") is not None:
        out["mesh"] = str(Path(out["mesh"]).expanduser().resolve())
    return out


#: generation settings that only say how new cycles would be simulated
_ENGINE_KEYS = ("scene.physics", "scene.coacd_threshold", "scene.max_convex_pieces", "scene.convex_merge_budget")


#: a setting that changes the piles only where it changes the part's bin (:func:`opnet.synthesis.layout.bin_geometry`)
_FILL_CAP = "scene.bin_max_fill"


def _fill_cap_inert(existing: Mapping[str, Any], scene: SceneConfig, obj: ObjectModel, drops: int) -> bool:
    """Whether ``scene`` with the dataset's own ``bin_max_fill`` (none when its file lacks the key)
    gives this part the same totes: a cap its bin already meets made the same piles."""
    made = existing.get("scene", {}).get("bin_max_fill") if isinstance(existing.get("scene"), dict) else None
    try:
        before = totes(obj, drops, dataclasses.replace(scene, bin_max_fill=made))
    except (TypeError, ValueError):  # a cap no scene accepts: the datasets differ
        return False
    return before == totes(obj, drops, scene)


def _differing(existing: Mapping[str, Any], expected: Mapping[str, Any]) -> list[str]:
    """Keys whose values differ, ``scene`` down to its fields (``scene.physics``); a dataset
    without ``scene.physics`` was made with pybullet."""
    out = []
    for key in sorted(set(expected) | set(existing)):
        a, b = existing.get(key), expected.get(key)
        if key == "scene" and isinstance(a, dict) and isinstance(b, dict):
            a = normal_recorded(a, MAX_SCENE_M)  # a working volume recorded before clip was one setting
            a, b = {"physics": "pybullet", **a}, {"physics": "pybullet", **b}
            out += [f"{key}.{k}" for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)]
        elif a != b:
            out.append(key)
    return out


def write_root_files(
    root: Path, obj: ObjectModel, object_config: Mapping[str, Any], params: IPAParameters, scene: SceneConfig,
    seed: int, drops: int, sensor: SensorModel | None = None, complete: bool = False,
) -> None:
    """Write (or check and rewrite) the dataset's root files before any scene.

    ``complete``: every cycle exists and none is to be made. Then the settings that only say how
    new cycles would be simulated (:data:`_ENGINE_KEYS`: the engine, e.g. a dataset made with
    pybullet before MuJoCo became the default, and its convex decomposition) may differ; the
    dataset's own ``generation.json`` is kept.

    Raises:
        ValueError: ``root`` already holds a dataset made with another object, seed, number of
            drops or scene settings (the message names the file and the differing keys).
    """
    generation = {"format": _FORMAT, "seed": int(seed), "drops": int(drops), "scene": scene.to_dict(),
                  "object": dict(object_config)}
    if sensor is not None and not sensor.is_ideal:  # ideal datasets keep the files of before sensors existed
        generation["sensor"] = sensor.to_dict()
    existing_file = root / GENERATION_FILE
    if existing_file.exists():
        try:
            existing = json.loads(existing_file.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError) as e:
            raise ValueError(f"{existing_file}: unreadable ({e}); delete the folder or choose another 'out'") from e
        expected = json.loads(_json_text(generation))
        differing = _differing(existing, expected)
        if _FILL_CAP in differing and _fill_cap_inert(existing, scene, obj, drops):
            differing.remove(_FILL_CAP)
            if not differing:
                generation = existing  # the same piles: the dataset keeps the file it was made with
        if complete and differing and all(key in _ENGINE_KEYS for key in differing):
            generation = existing  # a finished dataset is used as it was made
        elif differing:
            hint = ""
            if "scene.physics" in differing:
                made = existing.get("scene", {}).get("physics", "pybullet")
                hint = f"; to complete it, generate with scene.physics={made}"
            elif "scene.view_spin" in differing:
                made = str(existing.get("scene", {}).get("view_spin", False)).lower()
                hint = (f"; it was made with scene.view_spin={made} (scene.view_spin=auto decides by the part's hull): "
                        f"set scene.view_spin={made} to use it")
            raise ValueError(
                f"{existing_file}: the folder holds a dataset generated with other settings (keys {differing} differ"
                f"{hint}); choose another output folder or delete it"
            )
    root.mkdir(parents=True, exist_ok=True)
    # unchanged files are not rewritten: a complete dataset on read-only storage stays usable
    write_parameters(root, params)
    write_text_if_changed(root / OBJECT_FILE, _json_text(dict(object_config)))
    write_text_if_changed(root / POSEUTILS_FILE, _json_text(obj.to_poseutils()))
    write_text_if_changed(existing_file, _json_text(generation))
    for tmp in root.glob(".*.tmp"):  # left by a run killed while writing a root file
        tmp.unlink(missing_ok=True)


def cycle_complete(root: Path, cycle: int, drops: int) -> bool:
    """Whether every scene 000..drops of ``cycle`` has its three files, none of them empty (the
    CSV is written last, but a file truncated later, e.g. by a full disk, still shows)."""
    for n in range(drops + 1):
        for path in scene_paths(root, cycle, n).values():
            try:
                if path.stat().st_size == 0:
                    return False
            except OSError:
                return False
    return True


def clear_cycle(root: Path, cycle: int) -> None:
    """Delete every file of ``cycle`` (scenes, previews, temporary files of a killed run)."""
    folder = f"cycle_{cycle:04d}"
    for sub in _SCENE_DIRS:
        shutil.rmtree(root / sub / folder, ignore_errors=True)
    preview = root / PREVIEW_DIR
    if preview.is_dir():
        for f in [*preview.glob(f"{folder}_*.png"), *preview.glob(f".{folder}_*.tmp")]:
            f.unlink(missing_ok=True)


def bin_model_path(root: Path, cycle: int) -> Path:
    """The ``bin_model.json`` of ``cycle`` (written with ``scene.bin_models``)."""
    return root / "gt" / f"cycle_{cycle:04d}" / BIN_MODEL_FILE


def read_bin_model(root: Path, cycle: int) -> dict[str, Any]:
    """The bin model ``cycle``'s pile was made with (:func:`opnet.synthesis.cycle.bin_model_record`)."""
    path = bin_model_path(Path(root), cycle)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError as e:
        raise FileNotFoundError(f"{path}: not found (a dataset generated without scene.bin_models has none)") from e


def preview_path(root: Path, cycle: int, n: int) -> Path:
    return root / PREVIEW_DIR / f"cycle_{cycle:04d}_{n:03d}.png"


def write_cycle(root: Path, result: CycleResult, preview_scenes: tuple[int, ...] = ()) -> None:
    """Write the pile's bin model (``scene.bin_models`` only), the previews, then every scene in
    order (each scene's CSV last)."""
    if result.bin_model is not None:
        write_text_atomic(bin_model_path(root, result.cycle), _json_text(result.bin_model))
    for n in preview_scenes:
        write_preview(preview_path(root, result.cycle, n), result.records[n])
    for record in result.records:
        write_ipa_scene(root, result.cycle, record, (result.R_cam_bin, result.t_cam_bin))


def preview_cycles(cycles: int, previews: int) -> set[int]:
    """The cycles whose full scene gets a preview: ``previews`` cycles spread evenly."""
    if previews <= 0 or cycles <= 0:
        return set()
    if previews == 1 or cycles == 1:
        return {0}
    k = min(previews, cycles)
    return {round(i * (cycles - 1) / (k - 1)) for i in range(k)}


def read_generation(root: Path) -> dict[str, Any]:
    """The ``generation.json`` of a generated dataset (seed, drops, scene, object)."""
    path = Path(root) / GENERATION_FILE
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError as e:
        raise FileNotFoundError(f"{path}: not found (not a dataset made by opnet.synthesis)") from e
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: malformed JSON ({e.msg} at line {e.lineno})") from e
