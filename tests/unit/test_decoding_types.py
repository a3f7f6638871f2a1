"""A checkpoint's or a command line's decoding settings: booleans and fractions are not numbers of the
kind the setting holds, and are refused naming the key (they used to be read as 1, or kept as given)."""

from __future__ import annotations

import pytest

from opnet.objects import builtin_object
from opnet.parameterizations.averaging import PoseAveraging
from opnet.parameterizations.eve import EVEParameterization


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"threshold": True}, r"^parameterization.threshold=True: expected a number in \[0, 1\)$"),
    ({"min_visibility": False}, r"^parameterization.min_visibility=False: expected a number in \[0, 1\)$"),
    ({"min_visibility": "0.2"}, r"^parameterization.min_visibility='0.2': expected a number in \[0, 1\)$"),
    ({"averaging": "yes"}, r"^parameterization.averaging='yes': expected true or false$"),
    ({"averaging": 1}, r"^parameterization.averaging=1: expected true or false$"),
    ({"averaging": True, "averaging_eps": True}, r"^parameterization.averaging_eps=True: expected a fraction of delta in \(0, 100\]$"),
    ({"averaging": True, "averaging_eps": float("inf")}, r"^parameterization.averaging_eps=inf: expected a fraction of delta in \(0, 100\]$"),
    ({"averaging": True, "averaging_min_samples": 2.5}, r"^parameterization.averaging_min_samples=2.5: expected a whole number in \[1, 10000\]$"),
    ({"averaging": True, "averaging_min_samples": True}, r"^parameterization.averaging_min_samples=True: expected a whole number in \[1, 10000\]$"),
])  # fmt: skip
def test_decoding_settings_of_another_type_are_refused(kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        EVEParameterization(builtin_object("bracket"), grid=16, **kwargs)


def test_valid_decoding_settings_still_build() -> None:
    p = EVEParameterization(builtin_object("bracket"), grid=16, threshold=0.5, min_visibility=0.2, averaging=True,
                            averaging_eps=0.5, averaging_min_samples=2)  # fmt: skip
    assert isinstance(p.averaging, PoseAveraging) and p.averaging.min_samples == 2


@pytest.mark.parametrize(("averaging", "message"), [
    ({"eps": -1}, r"^decoding\.averaging\.eps=-1: expected a fraction of delta in \(0, 100\]$"),
    ({"eps": True}, r"^decoding\.averaging\.eps=True: expected a fraction of delta in \(0, 100\]$"),
    ({"min_samples": 0}, r"^decoding\.averaging\.min_samples=0: expected a whole number in \[1, 10000\]$"),
    ({"min_samples": 2.5}, r"^decoding\.averaging\.min_samples=2.5: expected a whole number in \[1, 10000\]$"),
    ({"cluster_score": "median"}, r"^decoding\.averaging\.cluster_score='median': expected one of max, sum, mean$"),
])  # fmt: skip
def test_an_override_is_named_as_the_user_wrote_it(averaging: dict, message: str) -> None:
    """eval.py / predict.py's +decoding.averaging.* overrides are refused naming that key (they named the
    training config's parameterization.averaging_* key, which the user never wrote)."""
    p = EVEParameterization(builtin_object("bracket"), grid=16, averaging=True)
    with pytest.raises(ValueError, match=message):
        p.with_decoding(averaging=averaging)
    assert p.with_decoding(averaging={"eps": 0.7, "min_samples": 3}).averaging.min_samples == 3
