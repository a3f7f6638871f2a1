"""A camera as one row of numbers: the one field order the ONNX graph's camera input, cached scenes and
checkpoint settings share (``CAMERA_FIELDS``), and bad rows refused with what is wrong."""

from __future__ import annotations

import numpy as np
import pytest

from opnet.geometry.camera import CAMERA_FIELDS, Camera


def test_a_row_lists_the_fields_in_order_and_reads_back_as_the_same_camera() -> None:
    cam = Camera(2320.26, 2320.15, 1053.13, 805.064, 2064, 1544, 1.5399, 2.8501)
    row = cam.row()
    assert row == [getattr(cam, f) for f in CAMERA_FIELDS] and row[4:6] == [2064.0, 1544.0]
    back = Camera.from_row(np.asarray(row, dtype=np.float64))
    assert back == cam and isinstance(back.width, int) and isinstance(back.height, int)


@pytest.mark.parametrize(("row", "match"), [
    ([100.0, 100.0, 64.0, 64.0, 128.0, 128.0, 0.5], "has 8 numbers"),
    ([100.0, 100.0, 64.0, 64.0, 128.5, 128.0, 0.5, 2.0], "whole pixels"),
    ([100.0, 100.0, 64.0, 64.0, 128.0, 128.0, 2.0, 0.5], "clip planes"),
])
def test_a_bad_row_is_refused_saying_what_is_wrong(row: list[float], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        Camera.from_row(row)

