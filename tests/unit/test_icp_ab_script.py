"""scripts/experiments/verification/icp_ab.py: its KEY=VALUE options read as YAML values; a malformed one is a clear error."""

from __future__ import annotations

import importlib.util

import pytest

from opnet.paths import REPO_ROOT

spec = importlib.util.spec_from_file_location("icp_ab", REPO_ROOT / "scripts" / "experiments" / "verification" / "icp_ab.py")
icp_ab = importlib.util.module_from_spec(spec)
spec.loader.exec_module(icp_ab)


def test_key_values_are_yaml_values() -> None:
    assert icp_ab.key_values(["averaging=false", "threshold=0.05", "score=p*v", "test_root=/a/b"], "--decoding") == {
        "averaging": False, "threshold": 0.05, "score": "p*v", "test_root": "/a/b"}


@pytest.mark.parametrize("bad", ["averaging", "=1"])
def test_a_value_without_key_or_equals_is_an_error(bad: str) -> None:
    with pytest.raises(ValueError, match=f"--decoding '{bad}': expected KEY=VALUE"):
        icp_ab.key_values([bad], "--decoding")


def test_a_search_variant_overrides_the_search_config() -> None:
    label, settings = icp_ab.search_variant("earlier:search.merge=0,icp.stride=1")
    assert label == "earlier" and settings.stride == 1 and settings.search.merge == 0
    assert settings.search.turn_step_deg == 5.0  # the rest as conf/refine/search.yaml


@pytest.mark.parametrize("bad", ["x:search.mrge=0", "x:solver.merge=0", "x:search.merge"])
def test_a_bad_search_variant_names_the_option(bad: str) -> None:
    with pytest.raises(ValueError, match=r"^--search-variant .*: expected LABEL:icp.KEY=VALUE"):
        icp_ab.search_variant(bad)
