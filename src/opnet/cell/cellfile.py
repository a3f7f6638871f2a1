"""The cell file ``conf/cell/<name>.yaml``: a cell's measured keys as ``python train.py experiment=cell
cell=<name>`` reads them (a ``_global_`` package: ``scene.*``, ``data.roi``, the sensor preset), with what
was measured and its spread over the frames in the comments above them."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from opnet.cell.estimate import Cell, spread_text
from opnet.paths import shared_dir

#: the keys of the cell ``experiment=cell`` takes from the cell file (or the command line); each is
#: mandatory there
MEASURED_KEYS = ("scene.camera_file", "scene.camera_height", "scene.camera_tilt_deg", "scene.camera_azimuth_deg",
                 "scene.clip", "scene.bin_area", "scene.bin_inner", "scene.bin_inner_y",
                 "scene.bin_wall_height", "scene.bin_wall_thickness", "scene.bin_clearance", "data.roi")


#: a cell's name: it names conf/cell/<name>.yaml and the data folder
CELL_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_-]{0,63}")


def check_cell_name(name: str, option: str) -> str:
    """``name`` if it may name a cell file, else a ValueError naming ``option``."""
    if not CELL_NAME.fullmatch(name):
        raise ValueError(f"{option} {name!r}: a cell's name is letters, digits, '_' and '-' (it names "
                         "conf/cell/<name>.yaml)")
    return name


def config_path(path: Path) -> str:
    """``path`` as a config value: under the reference data folder through ``${paths.shared_dir}`` (as the
    object configs name their meshes there), else absolute."""
    resolved, shared = Path(path).resolve(), shared_dir().resolve()
    if resolved.is_relative_to(shared):
        return f"${{paths.shared_dir}}/{resolved.relative_to(shared).as_posix()}"
    return resolved.as_posix()


def _num(value: float, digits: int = 4) -> str:
    text = f"{value:.{digits}f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def summary_lines(cell: Cell) -> list[str]:
    """What was found, with the spread over the frames (the console's lines and the file's comments)."""
    each = cell.per_frame()
    sides, drop = cell.sides, cell.support_drop
    lines = [f"camera over the bin floor (from each frame's floor: mean (min..max, spread)): "
             f"tilt {spread_text(each['camera_tilt_deg'], 2)} deg, azimuth {spread_text(each['camera_azimuth_deg'], 2)} deg, "
             f"height {spread_text(each['camera_height'], 4)} m (depth of the floor at the image centre)",
             f"bin inner {spread_text(each['bin_inner'], 3)} x {spread_text(each['bin_inner_y'], 3)} m, walls "
             f"{spread_text(each['bin_wall_height'], 3)} m high and {spread_text(each['bin_wall_thickness'], 3)} m thick "
             f"(walls seen on {'/'.join(str(v.walls_seen) for v in cell.views)} of 4 sides)",
             f"bin placed at x {spread_text(each['x'], 3)} m, y {spread_text(each['y'], 3)} m, yaw "
             f"{spread_text(each['yaw_deg'], 1)} deg (generator's world: origin where the image centre meets the floor)"]
    if cell.extrinsics is not None:
        lines.append(f"camera pose from the calibration; its base z axis and the frames' floor normal differ by "
                     f"{cell.extrinsics_error_deg:.2f} deg")
    if drop is None:
        lines.append("no plane seen below the bin: it stands on the floor (bin_clearance 0)")
    else:
        angles = [v.support_angle_deg for v in cell.views if v.support_angle_deg is not None]
        lines.append(f"the plane below drops {spread_text(each['support_drop'], 3)} m from the bin floor, "
                     f"{np.median(angles):.1f} deg off parallel: bin_clearance {cell.clearance:.3f} m"
                     + (" (the bin stands on it)" if cell.clearance == 0 else ""))
    area = ", ".join(_num(v, 3) for v in cell.area)
    grown = "given" if cell.area_margin is None else f"where the bin stood, plus {cell.area_margin:.3f} m"
    lines += [f"working area (bin centre) [{area}] m ({grown}); working volume {cell.clip[0]:.3f}-{cell.clip[1]:.3f} m "
              f"(the bin anywhere in it, any yaw, {cell.volume_margin:g} m above the rim and below the floor)",
              f"crop side auto:{_num(cell.crop_side, 2)} (1.1 x the bin's outer diagonal)"]
    return lines


def cell_yaml(cell: Cell, name: str, camera_file: Path, frames: str, sensor: str | None) -> str:
    """The cell file's text."""
    s = cell.sides
    lines = ["# @package _global_",
             f"# The cell {name!r}, written by opnet-cell from {len(cell.views)} frame(s) of {frames} (their depth "
             "only, no ground truth).",
             f"#   python train.py experiment=cell cell={name} object=<your part>",
             *(f"# {line}" for line in summary_lines(cell))]
    if sensor is None:
        lines.append("# no sensor preset chosen: give sensor=<preset> to train.py (opnet-cell check compares them)")
    else:
        lines += ["defaults:", f"  - override /sensor: {sensor}"]
    lines += ["cell:", f"  name: {name}", f"  frames: {len(cell.views)}", f"  sensor: {sensor or 'null'}"]
    if cell.extrinsics is not None:
        lines.append("  T_base_cam: [" + ", ".join("[" + ", ".join(_num(v, 6) for v in row) + "]"
                                                   for row in cell.extrinsics) + "]")
    area = ", ".join(_num(v, 3) for v in cell.area)
    lines += ["scene:", f"  camera_file: {config_path(camera_file)}",
              f"  camera_height: {_num(cell.camera_height)}", f"  camera_tilt_deg: {_num(cell.tilt_deg, 2)}",
              f"  camera_azimuth_deg: {_num(cell.azimuth_deg, 2)}",
              f"  clip: [{_num(cell.clip[0], 3)}, {_num(cell.clip[1], 3)}]",
              f"  bin_area: [{area}]", f"  bin_inner: {_num(s[0], 3)}", f"  bin_inner_y: {_num(s[1], 3)}",
              f"  bin_wall_height: {_num(cell.wall_height, 3)}", f"  bin_wall_thickness: {_num(cell.thickness, 3)}",
              f"  bin_clearance: {_num(cell.clearance, 3)}",
              "data:", f"  roi: auto:{_num(cell.crop_side, 2)}"]
    return "\n".join(lines) + "\n"
