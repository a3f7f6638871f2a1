"""A user's camera from a file: Siléane ``camera_params.txt``, IPA ``parameter.json`` or a YAML.

The YAML holds ``fx fy cx cy width height clip_start clip_end`` (pixels and metres; OpenCV
convention: pixel centres at integers, x right, y down); predict.py's ``camera.file`` also accepts
``depth_scale`` and partial files (the rest comes from the command line), the generator needs all
eight keys. Any camera YAML may carry ``T_base_cam``: the camera's pose in the robot's base frame
(4 x 4, metres, camera to base; a rigid transform), with which predict.py and the ONNX runtime
write poses in the base frame too. Every error names the file and the problem.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from opnet._repr import short_repr
from opnet.fileio.files import read_json, read_text
from opnet.geometry.camera import CAMERA_FIELDS, Camera
from opnet.geometry.frames import BASE_POSE_KEY, rigid_transform

YAML_CAMERA_KEYS = CAMERA_FIELDS
YAML_EXTRA_KEYS = ("depth_scale",)


def camera_number(value: Any, key: str, origin: str) -> float:
    """``value`` as a finite float, or a ValueError naming ``origin`` and ``camera.<key>``."""
    if isinstance(value, bool):  # YAML `true` and `camera.fx=true` would read as 1
        raise ValueError(f"{origin}: camera.{key}={value} is a boolean, not a number")
    try:
        x = float(value)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{origin}: camera.{key}={short_repr(value)} is not a number") from None
    if not math.isfinite(x):
        raise ValueError(f"{origin}: camera.{key}={short_repr(value)} is not finite")
    return x


class _DuplicateKey(Exception):
    pass


class UniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's safe loader, refusing a key given twice in one mapping (plain PyYAML keeps the
    last value without a word: ``fx: 600`` then ``fx: 6`` would read as 6)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        seen: set[Any] = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            try:
                if key in seen:
                    raise _DuplicateKey(f"key {short_repr(key)} is given twice (line {key_node.start_mark.line + 1})")
                seen.add(key)
            except TypeError:  # an unhashable key: the base class names it
                break
        return super().construct_mapping(node, deep)


UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, UniqueKeyLoader.construct_mapping)


def read_yaml(path: str | Path, what: str) -> Any:
    """The content of the YAML file ``path`` (``what`` it holds, for the messages): safe types
    only, each key once per mapping; every error one line naming the file."""
    path = Path(path)
    try:
        return yaml.load(read_text(path), Loader=UniqueKeyLoader)  # noqa: S506 - a SafeLoader subclass
    except _DuplicateKey as e:
        raise ValueError(f"{path}: {e} in the {what}; give each key once") from None
    except yaml.MarkedYAMLError as e:
        line = f" at line {e.problem_mark.line + 1}" if e.problem_mark is not None else ""
        raise ValueError(f"{path}: malformed {what} ({e.problem}{line})") from None
    except (yaml.YAMLError, RecursionError) as e:
        raise ValueError(f"{path}: malformed {what} ({type(e).__name__})") from None


def read_camera_yaml(path: str | Path, allowed: tuple[str, ...] = (*YAML_CAMERA_KEYS, *YAML_EXTRA_KEYS)) -> dict[str, float]:
    """The numbers of a camera YAML (keys among ``allowed``; null values are left out)."""
    return read_camera_yaml_pose(path, allowed)[0]


def read_camera_yaml_pose(path: str | Path, allowed: tuple[str, ...] = (*YAML_CAMERA_KEYS, *YAML_EXTRA_KEYS)
                          ) -> tuple[dict[str, float], np.ndarray | None]:
    """The numbers of a camera YAML (keys among ``allowed``; null values are left out) and its
    ``T_base_cam`` (a checked rigid transform, :func:`opnet.geometry.frames.rigid_transform`), or None."""
    path = Path(path)
    doc = read_yaml(path, "camera YAML")
    refuse_bop_scene_camera(doc, path)
    if not isinstance(doc, dict):
        raise ValueError(f"{path}: a camera YAML holds a mapping of {', '.join(allowed)}")
    doc = dict(doc)
    pose = doc.pop(BASE_POSE_KEY, None)
    unknown = sorted(set(map(str, doc)) - set(allowed))
    if unknown:
        raise ValueError(f"{path}: unknown camera key(s) {short_repr(unknown)}; expected {', '.join(allowed)} "
                         f"[{BASE_POSE_KEY}]")
    values = {str(k): camera_number(v, str(k), str(path)) for k, v in doc.items() if v is not None}
    return values, None if pose is None else rigid_transform(pose, str(path))


def read_camera_file(path: str | Path) -> Camera:
    """The camera of ``path``: a ``camera_params.txt`` (Siléane), a ``parameter.json`` (IPA), a
    ``.yaml`` / ``.yml`` with the eight keys, or a dataset folder holding one of the first two.

    Raises:
        FileNotFoundError: no such file.
        ValueError: an unknown kind of file, a missing key, a principal point outside the image,
            implausible values (each message names the file).
    """
    from opnet.datasets.ipa_params import PARAMETER_FILE, read_parameters
    from opnet.datasets.sileane import CAMERA_FILE, read_camera_params

    path = Path(path)
    if path.is_dir():
        found = [path / name for name in (CAMERA_FILE, PARAMETER_FILE) if (path / name).is_file()]
        if not found:
            raise FileNotFoundError(f"{path}: no {CAMERA_FILE} or {PARAMETER_FILE} in this folder")
        path = found[0]
    suffix = path.suffix.lower()
    if suffix in (".yaml", ".yml"):
        values = read_camera_yaml(path, YAML_CAMERA_KEYS)
        missing = [k for k in YAML_CAMERA_KEYS if k not in values]
        if missing:
            raise ValueError(f"{path}: missing camera key(s) {missing}; a camera YAML needs {', '.join(YAML_CAMERA_KEYS)}")
        for key in ("width", "height"):
            if not values[key].is_integer() or values[key] <= 0:
                raise ValueError(f"{path}: {key}={values[key]:g} must be a positive whole number of pixels")
        try:
            camera = Camera(values["fx"], values["fy"], values["cx"], values["cy"], int(values["width"]),
                            int(values["height"]), values["clip_start"], values["clip_end"])
        except ValueError as e:
            raise ValueError(f"{path}: {e}") from None
        camera.check_plausible(str(path))
    elif path.name.lower().endswith(".txt"):
        camera = read_camera_params(path)[0]
    elif suffix == ".json":
        refuse_bop_scene_camera(read_json(path, "an object of camera parameters"), path)
        camera = read_parameters(path).camera()
    else:
        raise ValueError(f"{path}: unknown camera file; expected a Siléane camera_params.txt, an IPA "
                         f"parameter.json or a .yaml with {', '.join(YAML_CAMERA_KEYS)}")
    return require_principal_point_inside(camera, str(path))


def dataset_camera(folder: str | Path) -> Camera | None:
    """The camera of a dataset folder (its ``camera_params.txt`` or ``parameter.json``), or None when it
    holds neither (a BOP split, a list of folders)."""
    from opnet.datasets.ipa_params import PARAMETER_FILE
    from opnet.datasets.sileane import CAMERA_FILE

    folder = Path(folder)
    if not any((folder / name).is_file() for name in (CAMERA_FILE, PARAMETER_FILE)):
        return None
    return read_camera_file(folder)


def refuse_bop_scene_camera(doc: Any, path: Path) -> None:
    """A ValueError naming ``path`` when ``doc`` is a BOP ``scene_camera.json`` (a ``cam_K`` per image
    id): its cameras belong to the images of a scene (read as a dataset), and it has no clip planes;
    read as a camera file it was blamed for lacking ``perspectiveAngle`` or for keys '0', '1', ..."""
    if not (isinstance(doc, dict) and doc and all(str(k).isdigit() for k in doc)
            and all(isinstance(v, dict) and "cam_K" in v for v in doc.values())):
        return
    raise ValueError(f"{path}: a BOP scene_camera.json (a cam_K for each of {len(doc)} image(s)), not a camera file; read "
                     "its split as a dataset (data.root=<split> data.object_id=<obj_id>), or give a camera YAML of "
                     f"{', '.join(YAML_CAMERA_KEYS)} (fx, fy, cx, cy = cam_K[0], cam_K[4], cam_K[2], cam_K[5]; the "
                     "clip planes of your working range, metres)")  # fmt: skip


def require_principal_point_inside(camera: Camera, source: str) -> Camera:
    """``camera`` if its principal point lies on the image (a camera's own optical axis does;
    only crops of images move it outside), else a ValueError naming ``source``."""
    if not (-0.5 <= camera.cx <= camera.width - 0.5 and -0.5 <= camera.cy <= camera.height - 0.5):
        raise ValueError(f"{source}: principal point ({camera.cx:g}, {camera.cy:g}) lies outside the "
                         f"{camera.width}x{camera.height} image (cx in [-0.5, {camera.width - 0.5:g}], "
                         f"cy in [-0.5, {camera.height - 0.5:g}]); pixels or metres mixed up?")
    return camera
