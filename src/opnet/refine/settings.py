"""The refinement's settings: :class:`ICPSettings` (with :class:`SearchSettings` for ``refine=search``) and
their making from the ``refine`` config group.

``conf/refine/<name>.yaml`` is read here and nowhere else below the command-line entry points
(:func:`refine_config`, which composes a file's defaults list as Hydra does): the runtime, which
reads no Hydra config, takes the settings of a refinement a model records by its name
(:func:`search_settings`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

#: how ICP pairs a model point with the scene: its nearest scene point (a k-d tree per hypothesis) | the
#: scene point of the pixel it projects onto (every hypothesis in one batch, several times faster)
ASSOCIATIONS = ("nearest", "projective")
#: the most threads an image's refinement may take
MAX_THREADS = 64


@dataclass(frozen=True)
class ICPSettings:
    """ICP settings; lengths in units of the object's diameter.

    Attributes:
        iterations: Gauss-Newton steps at most.
        radius: scene points within this distance of the hypothesis's origin are used.
        max_distance: correspondences farther apart are dropped.
        huber: the Huber threshold of the point-to-plane residual.
        min_points: fewer scene points (or correspondences) than this: the pose is kept.
        max_rotation_deg: a refinement that turns the pose by more (symmetry-aware) is rejected.
        max_translation: a refinement that moves the origin by more is rejected.
        budget_ms: time for all hypotheses of one image (None: no limit).
        model_points: points sampled on the mesh surface.
        stride: use every stride-th pixel of the depth image in each direction.
        local_points: at most about this many of the scene points near a hypothesis are fitted (every k-th
            of them; 0: all): on a megapixel frame the neighbourhood of a part holds tens of thousands.
        association: nearest (each model point's nearest scene point near the hypothesis) | projective
            (the scene point of the pixel it projects onto: every hypothesis in one batch; no pull
            along a surface, so a flat part's in-plane fit is left to the search).
        polish_association: the association of the ICP that polishes the search's poses (null: ``association``).
        converged: a pose stops when its step turns less than ``converged[0]`` radians and moves less than
            ``converged[1]`` metres (default a hundredth of a degree and of a millimetre, far below what the
            metric or a gripper can tell).
        min_gain: nearest-point ICP also stops when a step lowers the cost by less than this share of it (0:
            only by ``converged`` or when no step lowers it).
        threads: an image's hypotheses are refined in this many threads when there is no time budget (each
            thread a share of them, in batches; numpy's loops and the k-d tree release the interpreter): 2 keeps
            both cores of a 2-core CPU busy, 1 refines in the calling thread. Results do not depend on it.
        search: None (ICP only), or the depth-agreement search (:mod:`opnet.refine.search`) run
            after ICP on each hypothesis within the budget, its best pose polished by ICP again.
    """

    iterations: int = 20
    radius: float = 0.75
    max_distance: float = 0.1
    huber: float = 0.01
    min_points: int = 30
    max_rotation_deg: float = 20.0
    max_translation: float = 0.2
    budget_ms: float | None = 100.0
    model_points: int = 600
    stride: int = 1
    local_points: int = 0
    association: str = "nearest"
    polish_association: str | None = None
    converged: tuple[float, float] = (1e-4, 1e-5)
    min_gain: float = 1e-3
    threads: int = 2
    search: SearchSettings | None = None

    def __post_init__(self) -> None:
        positive = {"radius": self.radius, "max_distance": self.max_distance, "huber": self.huber,
                    "max_rotation_deg": self.max_rotation_deg, "max_translation": self.max_translation}  # fmt: skip
        for key, value in positive.items():
            if not (isinstance(value, int | float) and np.isfinite(value) and value > 0):
                raise ValueError(f"icp.{key} must be a positive number, got {value!r}")
        for key in ("iterations", "min_points", "model_points", "stride", "threads"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"icp.{key} must be a positive integer, got {value!r}")
        if self.threads > MAX_THREADS:
            raise ValueError(f"icp.threads must be at most {MAX_THREADS}, got {self.threads!r}")
        if isinstance(self.local_points, bool) or not isinstance(self.local_points, int) or self.local_points < 0:
            raise ValueError(f"icp.local_points must be an integer >= 0 (0: all), got {self.local_points!r}")
        converged = self.converged
        if isinstance(converged, str | bytes) or not hasattr(converged, "__len__") or len(converged) != 2 or not all(
                isinstance(v, int | float) and not isinstance(v, bool) and np.isfinite(v) and v > 0 for v in converged):
            raise ValueError(f"icp.converged must be two positive numbers [radians, metres], got {converged!r}")
        object.__setattr__(self, "converged", (float(converged[0]), float(converged[1])))
        if isinstance(self.min_gain, bool) or not isinstance(self.min_gain, int | float) or not 0 <= self.min_gain < 1:
            raise ValueError(f"icp.min_gain must be a number in [0, 1), got {self.min_gain!r}")
        for key in ("association", "polish_association"):
            value = getattr(self, key)
            if not (value in ASSOCIATIONS or (key == "polish_association" and value is None)):
                raise ValueError(f"icp.{key} must be one of {', '.join(ASSOCIATIONS)}"
                                 f"{' or null' if key == 'polish_association' else ''}, got {value!r}")
        if self.budget_ms is not None and not (np.isfinite(self.budget_ms) and self.budget_ms >= 0):
            raise ValueError(f"icp.budget_ms must be >= 0 or null, got {self.budget_ms!r}")

    @classmethod
    def from_config(cls, cfg: Any) -> ICPSettings:
        """From a mapping (a config group); unknown keys are an error naming them."""
        cfg = dict(cfg or {})
        unknown = set(cfg) - set(cls.__dataclass_fields__) | ({"search"} & set(cfg))
        if unknown:
            raise ValueError(f"icp: unknown keys {sorted(unknown)}; expected "
                             f"{', '.join(k for k in cls.__dataclass_fields__ if k != 'search')}")
        return cls(**cfg)


SCORES = ("agreement", "network", "product")
AXES = ("auto", "x", "y", "z")
MODES = ("auto", "turn", "flips")


@dataclass(frozen=True)
class SearchSettings:
    """Settings of the search; lengths in units of the object's diameter (:mod:`opnet.refine.search`).

    Attributes:
        axis: the model axis the part is turned about: auto (least spread of its points) | x | y | z.
        turn_step_deg: step of the turns (all the way round).
        shift: largest shift across the axis, each way.
        shift_step: step of the shift grid.
        tolerance: a measured depth within this of the model's agrees.
        turn_tolerance: ``turn`` (a flat part): the tolerance of its search and ranking instead (None:
            ``tolerance``). A pose across two stacked thin parts agrees with both at a loose one.
        see_through_weight: weight of the points the sensor sees through (measured behind the model).
        score: the refined hypothesis's score: agreement | network (the network's, unchanged) |
            product (network × max(agreement, 0)).
        suppress: after the search, a hypothesis within this many δ (the metric's threshold, pose
            distance, symmetry-aware) of a better-scored one is dropped: searches from nearby
            hypotheses end on the same pose, and the copy could only count as a false positive
            (0: keep all).
        coarse: 1 searches the whole grid; N > 1 first a grid N times coarser, then the fine grid
            around its three best turns (about N² times fewer candidates).
        fine: after the coarse grid (``coarse`` > 1): grid (the fine grid around its three best turns) | local
            (a pattern search of turns and shifts from them, a few dozen poses instead of a thousand).
        merge: before the refinement, a hypothesis whose origin lies within this many diameters of a
            better-scored one's is dropped (status ``suppressed``): the search from the better one reaches
            its pose (0: search from every hypothesis).
        mode: turn (about ``axis``, with shifts: flat parts) | flips (the ambiguity turns and a local
            search: any part) | auto (turn for a flat part, else flips).
        keep: ``flips``: how many of the best ambiguity turns go on to the local search.
        local_deg, local_shift (× diameter), local_rounds: ``flips``' local search (:mod:`opnet.refine.search`).
        anchor: ``turn``: a candidate's agreement less this × how far (× diameter) its origin moved from the
            hypothesis's, when candidates are compared (0: agreement alone).
        coarse_stride: the coarse grid (``coarse`` > 1) scores every this-th of a candidate's model points facing
            the camera (1: all): it only picks the turns the fine search starts from.
        suppress_icp: after the first ICP, a hypothesis whose pose lies within this many δ of a better-scored
            one's is dropped (status ``suppressed``) unsearched: it would search to the same pose (0: keep all).
        suppress_searched: the ``suppress`` test also runs right after the search, on the search's agreements,
            so that duplicates are not polished (False: only after the polish).
        rank_points: the final agreements, which rank the hypotheses, measured on this many model points of their
            own (a denser sample than ICP's ``model_points``: finer differences between near-equal poses; 0: ICP's).
        polish_share: only the searched hypotheses whose agreement is at least this share of the image's best are
            polished by ICP; the others keep the search's pose (status ``unpolished``) and rank by its agreement
            (0: all polished).
    """

    axis: str = "auto"
    turn_step_deg: float = 5.0
    shift: float = 0.1
    shift_step: float = 0.02
    tolerance: float = 0.04
    turn_tolerance: float | None = None
    see_through_weight: float = 1.0
    score: str = "agreement"
    suppress: float = 1.0
    coarse: int = 3
    merge: float = 0.1
    fine: str = "local"
    mode: str = "auto"
    keep: int = 3
    local_deg: float = 8.0
    local_shift: float = 0.04
    local_rounds: int = 4
    anchor: float = 0.0
    coarse_stride: int = 1
    suppress_icp: float = 0.0
    suppress_searched: bool = False
    polish_share: float = 0.0
    rank_points: int = 0

    def __post_init__(self) -> None:
        if self.fine not in ("grid", "local"):
            raise ValueError(f"search.fine must be grid or local, got {self.fine!r}")
        if self.mode not in MODES:
            raise ValueError(f"search.mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        for key, most in (("keep", 100), ("local_rounds", 100), ("rank_points", 20_000)):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= most:
                raise ValueError(f"search.{key} must be an integer in 0..{most}, got {value!r}")
        for key in ("local_deg", "local_shift"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value) or not 0 < value <= 90:
                raise ValueError(f"search.{key} must be a positive number (at most 90), got {value!r}")
        for key, most in (("anchor", 100), ("polish_share", 1)):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, int | float) or not 0 <= value <= most:
                raise ValueError(f"search.{key} must be a number in 0..{most}, got {value!r}")
        if self.axis not in AXES:
            raise ValueError(f"search.axis must be one of {', '.join(AXES)}, got {self.axis!r}")
        if self.score not in SCORES:
            raise ValueError(f"search.score must be one of {', '.join(SCORES)}, got {self.score!r}")
        for key in ("turn_step_deg", "shift_step", "tolerance"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value) or value <= 0:
                raise ValueError(f"search.{key} must be a positive number, got {value!r}")
        if self.turn_tolerance is not None and (isinstance(self.turn_tolerance, bool) or not isinstance(
                self.turn_tolerance, int | float) or not np.isfinite(self.turn_tolerance) or self.turn_tolerance <= 0):
            raise ValueError(f"search.turn_tolerance must be a positive number or null, got {self.turn_tolerance!r}")
        if not isinstance(self.suppress_searched, bool):
            raise ValueError(f"search.suppress_searched must be true or false, got {self.suppress_searched!r}")
        for key in ("shift", "see_through_weight", "suppress", "merge", "suppress_icp"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value) or value < 0:
                raise ValueError(f"search.{key} must be a number >= 0, got {value!r}")
        for key in ("coarse", "coarse_stride"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"search.{key} must be a positive integer, got {value!r}")
        if self.turn_step_deg > 360:
            raise ValueError(f"search.turn_step_deg must be at most 360, got {self.turn_step_deg!r}")
        if self.shift / self.shift_step > 50:
            raise ValueError(f"search: shift / shift_step = {self.shift / self.shift_step:g} makes a grid of more "
                             "than 101 x 101 shifts; take a larger shift_step")  # fmt: skip

    @classmethod
    def from_config(cls, cfg: Any) -> SearchSettings:
        """From a mapping (a config group); unknown keys are an error naming them."""
        cfg = dict(cfg or {})
        unknown = set(cfg) - set(cls.__dataclass_fields__)
        if unknown:
            raise ValueError(f"search: unknown keys {sorted(unknown)}; expected {', '.join(cls.__dataclass_fields__)}")
        return cls(**cfg)


def search_settings(budget_ms: float | None = None, name: str = "search") -> ICPSettings:
    """The settings of ``conf/refine/<name>.yaml``, a refinement with the search: ``search`` (ICP with a wider reach
    and a looser guard, then the search), ``search_fast`` (the first ICP projective, ten steps, a 1 % gain to go
    on) or ``search_flat`` (search_fast for a flat part), with a time budget of ``budget_ms`` per image (None:
    none): the runtime's ``--search`` and ``--search-fast``, and an export's recorded refinement."""
    settings = settings_from_config(refine_config(name))
    if settings is None or settings.search is None:
        raise ValueError(f"refine={name!r}: not a refinement with the search")
    return dataclasses.replace(settings, budget_ms=budget_ms)


def refine_config(name: str) -> dict[str, Any]:
    """``conf/refine/<name>.yaml`` as Hydra composes it: the files of its defaults list first, then its own keys."""
    from omegaconf import OmegaConf

    from opnet.paths import config_dir

    path = config_dir() / "refine" / f"{name}.yaml"
    if not path.is_file():
        raise ValueError(f"refine={name!r}: no {path}")
    own = OmegaConf.to_container(OmegaConf.load(path))
    defaults = own.pop("defaults", [])
    merged = OmegaConf.create()
    for entry in defaults:
        merged = OmegaConf.merge(merged, own if entry == "_self_" else refine_config(str(entry)))
    if "_self_" not in defaults:
        merged = OmegaConf.merge(merged, own)
    return OmegaConf.to_container(merged)


def model_refinement(refine: Any, recorded: str | None) -> tuple[Any, bool]:
    """The ``refine`` group of eval.py / predict.py resolved against the refinement a model records
    (:attr:`opnet.run_settings.RunSettings.refine`): ``refine=model`` (their default) is the recorded
    one's group, or none where the model records none. Returns (the group, whether it came from the model)."""
    if not refine or refine.get("method") != "model":
        return refine, False
    return ({"method": "none"} if recorded is None else refine_config(recorded)), recorded is not None


def settings_from_config(refine: Any) -> ICPSettings | None:
    """The ``refine`` config group (conf/refine/): ICP settings for ``method: icp``, ICP with the
    depth-agreement search for ``method: search`` (its settings from ``refine.search``), None for
    ``method: none`` or no group; ValueError for another method."""
    if not refine:
        return None
    method = refine.get("method", "none")
    if method == "none":
        return None
    if method == "model":
        raise ValueError("refine=model: the model's own refinement, resolved with its checkpoint (model_refinement)")
    if method not in ("icp", "search"):
        raise ValueError(f"refine.method={method!r}, expected none, icp or search")
    settings = ICPSettings.from_config(refine.get("icp"))
    if method == "search":
        settings = dataclasses.replace(settings, search=SearchSettings.from_config(refine.get("search")))
    return settings


__all__ = [
    "ASSOCIATIONS",
    "AXES",
    "MAX_THREADS",
    "MODES",
    "SCORES",
    "ICPSettings",
    "SearchSettings",
    "model_refinement",
    "refine_config",
    "search_settings",
    "settings_from_config",
]
