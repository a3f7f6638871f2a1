"""Benchmark the Brégier evaluator on synthetic scenes, and check it against a literal reference.

    python scripts/bench/bench_evaluate.py [--scenes 1000] [--instances 80] [--hypotheses 100]
                                     [--object bracket] [--check 20] [--seed 0]

Each scene: random ground-truth poses in a 0.6 x 0.4 x 0.2 m bin with varied occlusion rates (some
fully hidden); hypotheses = noisy copies of some instances (some beyond δ), duplicates of those,
and random false positives, with overlapping score distributions rounded to 3 decimals (ties).
Prints a table: scenes, instances, hypotheses, seconds, scenes/s. ``--check N`` also runs a
straightforward per-threshold loop in the manner of the official tool (sklearn nearest neighbours
on pose representatives, re-matched at every threshold) on N scenes and compares the curves.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from sklearn.neighbors import NearestNeighbors

from opnet.geometry import PoseSpace, quaternion_to_matrix
from opnet.metrics import (
    GroundTruthSet,
    HypothesisSet,
    evaluate_scene,
    evaluate_scenes,
    instances_to_find,
)
from opnet.objects import builtin_object


def random_rotations(rng: np.random.Generator, n: int) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    return quaternion_to_matrix(q / np.linalg.norm(q, axis=1, keepdims=True))


def perturb(
    rng: np.random.Generator, R: np.ndarray, t: np.ndarray, sigma_deg: float, sigma_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Rotate each pose by a random axis and a N(0, sigma_deg) angle; shift it by N(0, sigma_m)."""
    axes = rng.normal(size=(len(R), 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    half = np.radians(rng.normal(0.0, sigma_deg, len(R)))[:, None] / 2
    dR = quaternion_to_matrix(np.concatenate((np.cos(half), np.sin(half) * axes), axis=1))
    return dR @ R, t + rng.normal(0.0, sigma_m, t.shape)


def synthetic_scene(
    rng: np.random.Generator, n_gt: int, n_hyp: int, delta: float
) -> tuple[GroundTruthSet, HypothesisSet]:
    """Realistic-looking scene: ~55% noisy detections, ~15% duplicates, ~30% false positives."""
    R_gt = random_rotations(rng, n_gt)
    t_gt = rng.uniform((-0.3, -0.2, 0.0), (0.3, 0.2, 0.2), (n_gt, 3))
    occ = np.where(rng.random(n_gt) < 0.1, 1.0, rng.beta(1.2, 1.5, n_gt))
    gt = GroundTruthSet(R_gt, t_gt, occ)
    n_det = min(int(0.55 * n_hyp), n_gt)
    n_dup = min(int(0.15 * n_hyp), n_det)
    n_fp = n_hyp - n_det - n_dup
    which = rng.choice(n_gt, n_det, replace=False)
    R_det, t_det = perturb(rng, R_gt[which], t_gt[which], 4.0, 0.4 * delta)
    dup = rng.choice(n_det, n_dup, replace=True)
    R_dup, t_dup = perturb(rng, R_det[dup], t_det[dup], 3.0, 0.3 * delta)
    R_fp = random_rotations(rng, n_fp)
    t_fp = rng.uniform((-0.3, -0.2, 0.0), (0.3, 0.2, 0.2), (n_fp, 3))
    score = np.concatenate(
        (rng.normal(0.8, 0.12, n_det), rng.normal(0.6, 0.15, n_dup), rng.normal(0.4, 0.2, n_fp))
    )
    hyps = HypothesisSet(
        np.concatenate((R_det, R_dup, R_fp)), np.concatenate((t_det, t_dup, t_fp)), np.round(score, 3)
    )
    return gt, hyps


def reference_curve(
    gt: GroundTruthSet, hyps: HypothesisSet, space: PoseSpace, max_occlusion: float
) -> tuple[np.ndarray, np.ndarray]:
    """Per-threshold loop: nearest neighbours among representatives re-searched at every threshold."""
    K = space.num_representatives
    gt_reps = space.representatives(gt.R, gt.t)  # (N, K, D)
    hyp_reps = space.representatives(hyps.R, hyps.t)
    tree = NearestNeighbors(n_neighbors=1).fit(gt_reps.reshape(-1, gt_reps.shape[-1]))
    dist, idx = tree.kneighbors(hyp_reps[:, 0])
    nearest_gt, dmin = idx[:, 0] // K, dist[:, 0]
    to_find = set(np.flatnonzero(instances_to_find(gt, max_occlusion)).tolist())
    precision, recall = [], []
    for s in [np.inf, *sorted(set(hyps.score.tolist()), reverse=True)]:
        positives = np.flatnonzero(hyps.score >= s)
        tp = fp = 0
        if len(positives):
            flat = hyp_reps[positives].reshape(-1, hyp_reps.shape[-1])
            ptree = NearestNeighbors(n_neighbors=1).fit(flat)
            nearest_pos = positives[ptree.kneighbors(gt_reps[:, 0])[1][:, 0] // K]
            for i in positives:
                j = nearest_gt[i]
                if dmin[i] > space.delta or nearest_pos[j] != i:
                    fp += 1
                elif j in to_find:
                    tp += 1
        precision.append(tp / (tp + fp) if tp + fp else 1.0)
        recall.append(tp / len(to_find) if to_find else 1.0)
    return np.array(precision), np.array(recall)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", type=int, default=1000)
    ap.add_argument("--instances", type=int, default=80)
    ap.add_argument("--hypotheses", type=int, default=100)
    ap.add_argument("--object", default="bracket", help="built-in object (bracket, zbracket, shaft, pin)")
    ap.add_argument("--check", type=int, default=20, help="scenes compared with the reference loop (0: none)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    space = builtin_object(args.object).pose_space
    rng = np.random.default_rng(args.seed)
    scenes = {
        f"scene_{i:04d}": synthetic_scene(rng, args.instances, args.hypotheses, space.delta)
        for i in range(args.scenes)
    }

    start = time.perf_counter()
    summary = evaluate_scenes(scenes, space)
    seconds = time.perf_counter() - start
    print(f"{'scenes':>7} {'instances':>10} {'hypotheses':>11} {'seconds':>8} {'scenes/s':>9}")
    print(f"{args.scenes:>7} {args.instances:>10} {args.hypotheses:>11} {seconds:8.3f} {args.scenes / seconds:9.1f}")
    print(f"AP {summary.ap:.6f}  MAP {summary.map:.6f}  F1 {summary.f1:.6f}  R@P50 {summary.recall_at_p50:.4f}")

    if args.check > 0:
        names = list(scenes)[: args.check]
        start = time.perf_counter()
        reference = {n: reference_curve(*scenes[n], space, 0.5) for n in names}
        ref_seconds = time.perf_counter() - start
        worst = 0.0
        for n in names:
            curve = evaluate_scene(*scenes[n], space)
            p_ref, r_ref = reference[n]
            if curve.precision.shape != p_ref.shape:
                raise SystemExit(f"{n}: curve lengths differ ({len(curve.precision)} vs {len(p_ref)})")
            worst = max(worst, np.abs(curve.precision - p_ref).max(), np.abs(curve.recall - r_ref).max())
        status = "OK" if worst < 1e-12 else "MISMATCH"
        print(f"reference loop on {len(names)} scenes: {ref_seconds:.2f} s ({len(names) / ref_seconds:.1f} scenes/s); "
              f"max |difference| of the curves {worst:.2e}: {status}")
        if status != "OK":
            raise SystemExit(1)


if __name__ == "__main__":
    main()
