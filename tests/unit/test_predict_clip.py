"""predict.py clip=[near, far]: the model's working clip planes in place of the camera's; a bad
value is one error naming it."""

from __future__ import annotations

import pytest
from omegaconf import OmegaConf

from opnet.geometry.camera import parse_clip


def test_clip_reads_two_metres() -> None:
    assert parse_clip(None) is None
    assert parse_clip(OmegaConf.to_container(OmegaConf.create({"c": [1.55, 2.05]}).c)) == (1.55, 2.05)
    assert parse_clip([1, 2]) == (1.0, 2.0)


@pytest.mark.parametrize(("value", "message"), [
    ([2.05, 1.55], r"clip=\[2.05, 1.55\]: expected 0 < near < far"),
    ([0.5], r"clip=\[0.5\]: expected \[near, far\] in metres"),
    ("1.5", r"clip='1.5': expected \[near, far\] in metres"),
    ("12", r"clip='12': expected \[near, far\] in metres"),
    ([0.5, 1550.0], r"far <= 50 metres"),
])
def test_a_bad_clip_is_one_error(value, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        parse_clip(value)
