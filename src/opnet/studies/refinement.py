"""What the refinement studies share (``scripts/experiments/verification/icp_ab.py``,
``scripts/bench/bench_refine.py``): ``KEY=VALUE`` options read as YAML values, a variant of a
``conf/refine/`` group given on the command line, and the score of a set of refined scenes."""

from __future__ import annotations

import copy
import re
from typing import Any

import numpy as np


def key_values(values: list[str], option: str) -> dict[str, Any]:
    """``["averaging=false", "threshold=0.05"]`` -> {"averaging": False, "threshold": 0.05} (YAML
    values); ValueError naming ``option`` and a bad one."""
    import yaml

    out: dict[str, Any] = {}
    for v in values:
        key, sep, value = v.partition("=")
        if not sep or not key:
            raise ValueError(f"{option} {v!r}: expected KEY=VALUE")
        out[key] = yaml.safe_load(value) if value else None
    return out


def refine_variant(text: str, base: dict[str, Any], option: str) -> tuple[str, Any]:
    """``LABEL:KEY=VALUE[,KEY=VALUE...]`` -> (label, :class:`opnet.refine.ICPSettings` of the refine
    config ``base`` with ``icp.KEY`` / ``search.KEY`` overridden; a list value keeps its commas);
    ValueError naming ``option`` for a key ``base`` does not have or anything else malformed."""
    import yaml

    from opnet.refine import settings_from_config

    label, _, pairs = text.partition(":")
    conf = copy.deepcopy(base)
    try:
        for pair in filter(None, re.split(r",(?![^\[]*\])", pairs)):  # a list value keeps its commas
            key, value = pair.split("=", 1)
            section, name = key.strip().split(".", 1)
            if section not in ("icp", "search") or name not in conf[section]:
                raise KeyError(key)
            conf[section][name] = yaml.safe_load(value)
        return label.strip(), settings_from_config(conf)
    except (ValueError, KeyError) as e:
        raise ValueError(f"{option} {text!r}: expected LABEL:icp.KEY=VALUE,search.KEY=VALUE ({e})") from None


def score_refined(scenes: dict[str, Any], obj: Any, max_occlusion: float) -> dict[str, float]:
    """AP (Brégier), found share and the matched translation / rotation error percentiles (p50, p90) of
    scenes ``{name: (ground truth, hypotheses)}``."""
    from opnet.metrics.bregier import evaluate_scenes
    from opnet.metrics.diagnostics import scene_outcomes

    result = evaluate_scenes(scenes, obj.pose_space, max_occlusion=max_occlusion)
    outcomes = scene_outcomes(scenes, obj.pose_space, obj.diameter, max_occlusion)
    t = np.concatenate([o.t_err_mm for o in outcomes]) if outcomes else np.zeros(0)
    r = np.concatenate([o.r_err_deg for o in outcomes]) if outcomes else np.zeros(0)
    find = sum(int(o.find.sum()) for o in outcomes)
    found = sum(int((o.find & (o.outcome == "matched")).sum()) for o in outcomes)

    def pct(x: np.ndarray, q: float) -> float:
        return float(np.percentile(x, q)) if len(x) else float("nan")

    return {"ap": result.ap, "found": found / max(find, 1), "t_mm_p50": pct(t, 50), "t_mm_p90": pct(t, 90),
            "r_deg_p50": pct(r, 50), "r_deg_p90": pct(r, 90)}  # fmt: skip


__all__ = ["key_values", "refine_variant", "score_refined"]
