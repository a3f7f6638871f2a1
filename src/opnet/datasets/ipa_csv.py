"""Ground-truth CSV of a Fraunhofer IPA scene, ``gt/cycle_XXXX/NNN.csv``
(docs/formats.md#fraunhofer-ipa-layout).

One row per instance after a header; row ``id`` 0 is the bin, rows 1..N the objects. Columns:
``id, class, x, y, z`` (metres), the object's x-, y- and z-axis vectors (``R = [x | y | z]``, i.e.
the rotation stored column-major), ``visibility_score_o`` (orthographic) and ``visibility_score_p``
(perspective). Poses are in IPA's camera frame (x and y negated); this module converts them to and
from the internal OpenCV camera frame, so nothing else has to.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from opnet.datasets.validate import MAX_IPA_VISIBILITY, check_poses, check_range
from opnet.fileio.atomic import write_text_atomic
from opnet.fileio.files import read_text
from opnet.geometry.frames import camera_to_ipa, ipa_to_camera

CSV_HEADER = (
    "id,class,x,y,z,"
    "rot_x_axis_1,rot_x_axis_2,rot_x_axis_3,rot_y_axis_1,rot_y_axis_2,rot_y_axis_3,"
    "rot_z_axis_1,rot_z_axis_2,rot_z_axis_3,visibility_score_o,visibility_score_p"
).split(",")
BIN_ID = 0
#: the CSV id is the object's value in the uint8 segmentation PNG (255 = background)
MAX_CSV_ID = 254


@dataclass
class IPAGroundTruth:
    """The objects and the bin of one IPA scene, in the internal camera frame.

    Attributes:
        instance_id: (N,) int64 CSV ids of the objects (1..N in IPA data; the segmentation value).
        object_class: (N,) int64 ``class`` column.
        R_cam_obj: (N, 3, 3) float64 rotations. t_cam_obj: (N, 3) float64 metres.
        visibility_o, visibility_p: (N,) float64 orthographic / perspective visibility scores
            (may exceed 1 in IPA data).
        R_cam_bin, t_cam_bin: (3, 3), (3,) float64 bin pose (row id 0), or None without a bin row.
    """

    instance_id: np.ndarray
    object_class: np.ndarray
    R_cam_obj: np.ndarray
    t_cam_obj: np.ndarray
    visibility_o: np.ndarray
    visibility_p: np.ndarray
    R_cam_bin: np.ndarray | None = None
    t_cam_bin: np.ndarray | None = None


def read_ipa_csv(path: str | Path) -> IPAGroundTruth:
    """Read a ground-truth CSV.

    Raises:
        FileNotFoundError: no such file.
        ValueError: missing header, wrong column count, unparsable or non-finite value, duplicate
            or out-of-range id, a rotation that is not one (scaled, a reflection), an implausible
            translation or visibility (:mod:`opnet.datasets.validate`); the message names the file
            and the line.
    """
    path = Path(path)
    text = read_text(path).removeprefix("\ufeff")  # a UTF-8 byte-order mark (spreadsheet exports)
    rows = [
        (i + 1, r) for i, r in enumerate(csv.reader(io.StringIO(text))) if any(c.strip() for c in r)
    ]
    if not rows or rows[0][1][0].strip() != "id":
        raise ValueError(f"{path}: line 1: expected the header {','.join(CSV_HEADER)}")
    ids, classes, numbers = [], [], []
    for line, row in rows:
        if len(row) != len(CSV_HEADER):
            raise ValueError(f"{path}: line {line}: {len(row)} columns, expected {len(CSV_HEADER)}")
        if line == rows[0][0]:
            continue
        try:
            ids.append(int(row[0]))
            classes.append(int(row[1]))
            values = [float(c) for c in row[2:]]
        except ValueError as e:
            raise ValueError(f"{path}: line {line}: unparsable value ({e})") from None
        if not all(math.isfinite(v) for v in values) or ids[-1] < 0:
            raise ValueError(
                f"{path}: line {line}: expected finite numbers and a non-negative id, got {row}"
            )
        if ids[-1] in ids[:-1]:
            raise ValueError(f"{path}: line {line}: duplicate id {ids[-1]}")
        if ids[-1] > MAX_CSV_ID:
            raise ValueError(f"{path}: line {line}: id {ids[-1]} exceeds {MAX_CSV_ID} (ids are the values of the "
                             "8-bit segmentation image: 0 = bin, 255 = background)")
        numbers.append(values)
    table = np.array(numbers).reshape(-1, 14)
    lines = [line for line, _ in rows[1:]]

    def where(i: int) -> str:
        return f"{path}: line {lines[i]}"

    check_poses(table[:, 3:12].reshape(-1, 3, 3), table[:, 0:3], where)
    for column, name in ((12, "visibility_score_o"), (13, "visibility_score_p")):
        check_range(table[:, column], 0.0, MAX_IPA_VISIBILITY, name, where)
    return _ground_truth(np.array(ids, np.int64), np.array(classes, np.int64), table)


def _ground_truth(ids: np.ndarray, classes: np.ndarray, numbers: np.ndarray) -> IPAGroundTruth:
    t_ipa = numbers[:, 0:3]
    R_ipa = (
        numbers[:, 3:12].reshape(-1, 3, 3).transpose(0, 2, 1)
    )  # rows of the CSV block are columns of R
    R_cam, t_cam = ipa_to_camera(R_ipa, t_ipa)
    obj = ids != BIN_ID
    bin_rows = np.flatnonzero(~obj)
    return IPAGroundTruth(
        instance_id=ids[obj],
        object_class=classes[obj],
        R_cam_obj=R_cam[obj],
        t_cam_obj=t_cam[obj],
        visibility_o=numbers[obj, 12],
        visibility_p=numbers[obj, 13],
        R_cam_bin=R_cam[bin_rows[0]] if len(bin_rows) else None,
        t_cam_bin=t_cam[bin_rows[0]] if len(bin_rows) else None,
    )


def write_ipa_csv(path: str | Path, gt: IPAGroundTruth) -> None:
    """Write a ground-truth CSV atomically; floats in ``%.17g`` so float64 values read back exactly.

    The bin row (id 0, class 0, visibilities 1) comes first when ``gt`` has a bin pose.
    """
    ids, classes = list(gt.instance_id), list(gt.object_class)
    R, t = gt.R_cam_obj, gt.t_cam_obj
    vis = np.stack([gt.visibility_o, gt.visibility_p], axis=-1).reshape(-1, 2)
    if gt.R_cam_bin is not None and gt.t_cam_bin is not None:
        ids, classes = [BIN_ID, *ids], [0, *classes]
        R = np.concatenate([np.asarray(gt.R_cam_bin).reshape(1, 3, 3), R])
        t = np.concatenate([np.asarray(gt.t_cam_bin).reshape(1, 3), t])
        vis = np.concatenate([np.ones((1, 2)), vis])
    R_ipa, t_ipa = camera_to_ipa(np.asarray(R, np.float64), np.asarray(t, np.float64))
    lines = [",".join(CSV_HEADER)]
    for i in range(len(ids)):
        values = [*t_ipa[i], *R_ipa[i].T.reshape(9), *vis[i]]
        lines.append(
            ",".join([str(int(ids[i])), str(int(classes[i]))] + [f"{v:.17g}" for v in values])
        )
    write_text_atomic(path, "\n".join(lines) + "\n")
