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
    ({"treshold": 0.05}, r"^decoding.treshold=0.05: unknown setting; expected one of threshold, min_visibility, score, turns, averaging$"),
    ({"score": "q"}, "decoding.score=.q.: expected one of"),
    ({"averaging": {"radius": 2}}, r"^decoding.averaging.radius=2: unknown setting; expected one of eps, min_samples, cluster_score, keep_noise$"),
])
def test_a_wrong_decoding_override_is_one_error(overrides: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        with_decoding_overrides(EVEParameterization(builtin_object("bracket")), overrides)


@pytest.mark.parametrize(("override", "message"), [
    ({"threshold": 2}, "decoding.threshold=2: expected a number in [0, 1)"),
    ({"threshold": -0.5}, "decoding.threshold=-0.5: expected a number in [0, 1)"),
    ({"threshold": float("nan")}, "decoding.threshold=nan: expected a number in [0, 1)"),
    ({"threshold": True}, "decoding.threshold=True: expected a number in [0, 1)"),
    ({"threshold": "abc"}, "decoding.threshold='abc': expected a number in [0, 1)"),
    ({"min_visibility": 5}, "decoding.min_visibility=5: expected a number in [0, 1)"),
    ({"averaging": "maybe"}, "decoding.averaging='maybe': expected true, false or a mapping"),
    ({"score": "best"}, "decoding.score='best': expected one of"),
])  # fmt: skip
def test_command_line_decoding_overrides_are_checked_like_a_checkpoints(override: dict, message: str) -> None:
    """The values a checkpoint's decoding is refused for are refused from the command line too, one line each."""
    from opnet.cli.eval import with_decoding_overrides
    from opnet.objects import builtin_object
    from opnet.parameterizations.vanilla import VanillaParameterization

    param = VanillaParameterization(builtin_object("zbracket"), grid=8)
    with pytest.raises(ValueError) as e:
        with_decoding_overrides(param, override)
    assert message in str(e.value) and "\n" not in str(e.value)
    assert with_decoding_overrides(param, {"averaging": True}).averaging is not None  # true: averaging on
