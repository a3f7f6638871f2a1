"""A checkpoint's or a command line's decoding settings: booleans and fractions are not numbers of the
kind the setting holds, and are refused naming the key (they used to be read as 1, or kept as given)."""

from __future__ import annotations

import pytest

from opnet.objects import builtin_object
from opnet.parameterizations.averaging import PoseAveraging
from opnet.parameterizations.eve import EVEParameterization


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"threshold": True}, r"parameterization.threshold must lie in \[0, 1\), got True"),
    ({"min_visibility": False}, r"parameterization.min_visibility must lie in \[0, 1\), got False"),
    ({"min_visibility": "0.2"}, r"parameterization.min_visibility must lie in \[0, 1\), got '0.2'"),
    ({"averaging": "yes"}, r"parameterization.averaging must be true or false, got 'yes'"),
    ({"averaging": 1}, r"parameterization.averaging must be true or false, got 1"),
    ({"averaging": True, "averaging_eps": True}, r"averaging_eps must be a positive number .*got True"),
    ({"averaging": True, "averaging_eps": float("inf")}, r"averaging_eps must be a positive number .*got inf"),
    ({"averaging": True, "averaging_min_samples": 2.5}, r"averaging_min_samples must be a whole number >= 1, got 2.5"),
    ({"averaging": True, "averaging_min_samples": True}, r"averaging_min_samples must be a whole number >= 1, got True"),
])  # fmt: skip
def test_decoding_settings_of_another_type_are_refused(kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        EVEParameterization(builtin_object("bracket"), grid=16, **kwargs)


def test_valid_decoding_settings_still_build() -> None:
    p = EVEParameterization(builtin_object("bracket"), grid=16, threshold=0.5, min_visibility=0.2, averaging=True,
                            averaging_eps=0.5, averaging_min_samples=2)  # fmt: skip
    assert isinstance(p.averaging, PoseAveraging) and p.averaging.min_samples == 2


@pytest.mark.parametrize(("averaging", "message"), [
    ({"eps": -1}, r"^decoding\.averaging\.eps must be a positive number \(a fraction of delta\), got -1$"),
    ({"eps": True}, r"^decoding\.averaging\.eps must be a positive number .*got True$"),
    ({"min_samples": 0}, r"^decoding\.averaging\.min_samples must be >= 1, got 0$"),
    ({"min_samples": 2.5}, r"^decoding\.averaging\.min_samples must be a whole number >= 1, got 2.5$"),
    ({"cluster_score": "median"}, r"^decoding\.averaging\.cluster_score must be one of .*got 'median'$"),
])  # fmt: skip
def test_an_override_is_named_as_the_user_wrote_it(averaging: dict, message: str) -> None:
    """eval.py / predict.py's +decoding.averaging.* overrides are refused naming that key (they named the
    training config's parameterization.averaging_* key, which the user never wrote)."""
    p = EVEParameterization(builtin_object("bracket"), grid=16, averaging=True)
    with pytest.raises(ValueError, match=message):
        p.with_decoding(averaging=averaging)
    assert p.with_decoding(averaging={"eps": 0.7, "min_samples": 3}).averaging.min_samples == 3
