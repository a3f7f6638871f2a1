"""eval.py decoding=: the checkpoint's decoding overridden at evaluation (threshold, score,
min_visibility, averaging), unchanged when nothing is given, one error naming a wrong key."""

from __future__ import annotations

import pytest
from omegaconf import OmegaConf

from opnet.cli.eval import with_decoding_overrides
from opnet.objects import builtin_object
from opnet.parameterizations import EVEParameterization


def test_decoding_overrides_replace_the_checkpoints_settings() -> None:
    param = EVEParameterization(builtin_object("bracket"), threshold=0.1)
    assert param.averaging is not None
    assert with_decoding_overrides(param, OmegaConf.create({})) is param
    new = with_decoding_overrides(param, OmegaConf.create({"threshold": 0.05, "averaging": False, "score": "p*v"}))
    assert new.threshold == 0.05 and new.averaging is None and new.score == "p*v"
    assert param.threshold == 0.1 and param.averaging is not None  # the loaded one untouched
    wider = with_decoding_overrides(param, {"averaging": {"eps": 1.5}})
    assert wider.averaging.eps == 1.5


@pytest.mark.parametrize(("overrides", "message"), [
    ({"treshold": 0.05}, r"decoding=\{'treshold': 0.05\}: with_decoding: unknown setting 'treshold'"),
    ({"score": "q"}, "parameterization score must be one of"),
    ({"averaging": {"radius": 2}}, r"unknown averaging settings \['radius'\]"),
])
def test_a_wrong_decoding_override_is_one_error(overrides: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        with_decoding_overrides(EVEParameterization(builtin_object("bracket")), overrides)
