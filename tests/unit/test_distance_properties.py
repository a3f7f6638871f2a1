"""Property tests of the Brégier pose distance (PoseSpace), as the evaluator uses it
(docs/method.md#pose-distance): a metric on poses modulo the object's proper symmetries."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import minimize_scalar

from opnet.geometry import PoseSpace, axis_angle_rotation, quaternion_to_matrix
from opnet.geometry.symmetry import dihedral_group
from opnet.objects import ObjectModel, builtin_object, load_object

PROPERTY = settings(max_examples=30, deadline=None, derandomize=True)

MESH_OBJECTS = {
    "ring_screw": ("IPARingScrew.stl", {"kind": "cyclic", "order": 2}),
    "gear_shaft": ("IPAGearShaft.stl", {"kind": "revolution"}),
}
OBJECTS = [
    "bracket", "zbracket", "shaft", "pin", "dihedral",
    *(pytest.param(name, marks=pytest.mark.shared) for name in MESH_OBJECTS),
]


def load(name: str, request: pytest.FixtureRequest) -> ObjectModel:
    if name in MESH_OBJECTS:
        file, symmetry = MESH_OBJECTS[name]
        return load_object(name, mesh=request.getfixturevalue("meshes_dir") / file, symmetry=symmetry)
    return builtin_object(name)


@pytest.fixture(scope="module", params=OBJECTS)
def space(request: pytest.FixtureRequest) -> PoseSpace:
    if request.param == "dihedral":  # a finite group beyond cyclic; Λ commutes with it
        return PoseSpace(np.diag([0.02, 0.02, 0.05]), dihedral_group(4), delta=0.01)
    return load(request.param, request).pose_space


quaternions = st.tuples(*[st.floats(-1, 1) for _ in range(4)]).filter(lambda q: np.linalg.norm(q) > 0.1)
translations = st.tuples(*[st.floats(-0.5, 0.5) for _ in range(3)])
angles = st.floats(-np.pi, np.pi)


def pose(q: tuple[float, ...], t: tuple[float, ...]) -> tuple[torch.Tensor, torch.Tensor]:
    return quaternion_to_matrix(torch.tensor(q, dtype=torch.float64)), torch.tensor(t, dtype=torch.float64)


def dist(space: PoseSpace, a: tuple[torch.Tensor, torch.Tensor], b: tuple[torch.Tensor, torch.Tensor]) -> float:
    return float(space.distance(a[0], a[1], b[0], b[1]))


def tolerance(space: PoseSpace) -> float:
    # a mesh's Λ commutes with its symmetry group only up to the mesh's own asymmetry (~1e-7 m)
    return 1e-6 if not space.revolution else 1e-9


@PROPERTY
@given(q=quaternions, t=translations, spin=angles)
def test_zero_between_symmetric_equivalents(space: PoseSpace, q, t, spin: float) -> None:
    R, tt = pose(q, t)
    for g in torch.from_numpy(space.group):
        equivalent = R @ g
        if space.revolution:  # any spin about the axis, before or after the flip
            equivalent = R @ axis_angle_rotation("Z", torch.tensor(spin, dtype=torch.float64)) @ g
        assert dist(space, (R, tt), (equivalent, tt)) < 1e-7


@PROPERTY
@given(q1=quaternions, t1=translations, q2=quaternions, t2=translations)
def test_symmetric_in_its_arguments(space: PoseSpace, q1, t1, q2, t2) -> None:
    a, b = pose(q1, t1), pose(q2, t2)
    assert dist(space, a, b) == pytest.approx(dist(space, b, a), abs=tolerance(space))


@PROPERTY
@given(q1=quaternions, t1=translations, q2=quaternions, t2=translations, qc=quaternions, tc=translations)
def test_invariant_to_a_common_change_of_frame(space: PoseSpace, q1, t1, q2, t2, qc, tc) -> None:
    (R1, t1_), (R2, t2_), (Q, u) = pose(q1, t1), pose(q2, t2), pose(qc, tc)
    moved = dist(space, (Q @ R1, Q @ t1_ + u), (Q @ R2, Q @ t2_ + u))
    assert moved == pytest.approx(dist(space, (R1, t1_), (R2, t2_)), abs=1e-9)


@PROPERTY
@given(q1=quaternions, t1=translations, q2=quaternions, t2=translations, q3=quaternions, t3=translations)
def test_triangle_inequality(space: PoseSpace, q1, t1, q2, t2, q3, t3) -> None:
    a, b, c = pose(q1, t1), pose(q2, t2), pose(q3, t3)
    assert dist(space, a, c) <= dist(space, a, b) + dist(space, b, c) + tolerance(space)


@pytest.mark.parametrize("name", ["shaft", "pin", pytest.param("gear_shaft", marks=pytest.mark.shared)])
@settings(max_examples=20, deadline=None, derandomize=True)
@given(q1=quaternions, t1=translations, q2=quaternions, t2=translations)
def test_revolution_closed_form_is_the_minimum_over_spins(request, name: str, q1, t1, q2, t2) -> None:
    """sqrt(|dt|^2 + lam^2 |R1 e_z - R2 e_z|^2) equals min over spins θ (and the flip) of the
    finite-group distance with Λ = diag(λr, λr, λz), found numerically."""
    obj = load(name, request)
    lam_r, lam_z, _ = obj.lam_revolution
    Lambda = np.diag([lam_r, lam_r, lam_z])
    (R1, T1), (R2, T2) = (tuple(x.numpy() for x in pose(q, t)) for q, t in ((q1, t1), (q2, t2)))

    def squared(theta: float, g: np.ndarray) -> float:
        Rz = axis_angle_rotation("Z", np.array(theta))
        return float(np.sum((T1 - T2) ** 2) + np.sum(((R1 - R2 @ Rz @ g) @ Lambda) ** 2))

    best = np.inf
    grid = np.linspace(-np.pi, np.pi, 721)
    spins = axis_angle_rotation("Z", grid)  # (721, 3, 3)
    step = grid[1] - grid[0]
    for g in obj.symmetry.group():
        on_grid = np.sum(((R1 - R2 @ spins @ g) @ Lambda) ** 2, axis=(1, 2))
        theta0 = grid[np.argmin(on_grid)]
        res = minimize_scalar(squared, bounds=(theta0 - step, theta0 + step), args=(g,), method="bounded",
                              options={"xatol": 1e-10})
        best = min(best, res.fun)
    closed = dist(obj.pose_space, (torch.from_numpy(R1), torch.from_numpy(T1)), (torch.from_numpy(R2), torch.from_numpy(T2)))
    assert closed == pytest.approx(np.sqrt(best), rel=1e-7, abs=1e-10)


def test_flip_distinguishes_pin_from_shaft() -> None:
    """Upside down is the same pose for the pin (rotoreflection), a far one for the shaft."""
    flip = torch.diag(torch.tensor([1.0, -1.0, -1.0], dtype=torch.float64))
    eye, zero = torch.eye(3, dtype=torch.float64), torch.zeros(3, dtype=torch.float64)
    pin, shaft = builtin_object("pin").pose_space, builtin_object("shaft").pose_space
    assert float(pin.distance(eye, zero, flip, zero)) < 1e-12
    assert float(shaft.distance(eye, zero, flip, zero)) == pytest.approx(2 * shaft.lam)


@pytest.mark.shared
def test_bunny_distance_is_the_official_formula(bunny_sample: Path) -> None:
    """The official poseutils Λ: d^2 = |dt|^2 + ||(R1 - R2) Λ||_F^2 (no symmetry)."""
    space = ObjectModel.from_poseutils(bunny_sample / "poseutils.json").pose_space
    rng = np.random.default_rng(0)
    q = rng.normal(size=(2, 4))
    R = quaternion_to_matrix(q / np.linalg.norm(q, axis=1, keepdims=True))
    t = rng.normal(size=(2, 3))
    Lambda = np.diag([0.0263663, 0.0338224, 0.0484393])
    expected = np.sqrt(np.sum((t[0] - t[1]) ** 2) + np.sum(((R[0] - R[1]) @ Lambda) ** 2))
    got = space.distance(torch.from_numpy(R[0]), torch.from_numpy(t[0]), torch.from_numpy(R[1]), torch.from_numpy(t[1]))
    assert float(got) == pytest.approx(expected, rel=1e-12)
