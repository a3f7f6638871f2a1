"""ONNX export and the torch-free deployment: every parameterization's graph equals PyTorch's
dense decoding, the deployment path gives the same hypotheses as predict.py's PyTorch path on
recorded dataset images in a process where ``import torch`` fails, and bad input is refused."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from conftest import compose_cfg
from opnet.cli import export as export_cli
from opnet.cli.build import build_components, load_checkpoint
from opnet.data.preprocess import to_network_input
from opnet.datasets.ipa import IPADataset
from opnet.deploy.export import export_onnx
from opnet.geometry.pose_numpy import closest_equivalent, pose_distance
from opnet.objects import builtin_object
from opnet.paths import REPO_ROOT
from param_checks import assert_export_matches, parameterization_names
from opnet.refine import ICPSettings

pytest.importorskip("onnxruntime")
from opnet.deploy.runtime import OnnxPoseEstimator  # noqa: E402


@pytest.mark.parametrize("param", parameterization_names())
def test_every_parameterization_exports_and_matches_pytorch(param: str, tmp_path: Path) -> None:
    cfg = compose_cfg("train", ["model=tiny", "object=zbracket", f"parameterization={param}"])
    # the untrained weights fixed: drawn from whatever state the tests before left, a draw whose rotation columns
    # stand nearly parallel in some cell turns ONNX Runtime's last-bit differences into 1e-4 of a rotation entry
    torch.manual_seed(0)
    system = build_components(cfg).system.eval()
    meta = assert_export_matches(system, cfg, tmp_path / f"{param}.onnx")
    assert meta["parameterization"] == param



def test_the_runtime_reads_mps_slots_as_pytorch_does(tmp_path: Path) -> None:
    """MP's slot l + 1 counts only where slots 1..l are present: the runtime's hypotheses are PyTorch's, not
    every slot above the threshold (it read each slot alone before)."""
    import torch

    from opnet.cli import export as export_cli
    from opnet.geometry.camera import Camera

    cfg = compose_cfg("train", ["model=tiny", "object=zbracket", "parameterization=mp"])
    torch.manual_seed(0)  # an untrained network: some draws leave no second slot without its first
    system = build_components(cfg).system.eval()
    meta = export_onnx(system, cfg, Path("none.ckpt"), tmp_path / "mp.onnx")
    images, cams = export_cli.synthetic_inputs(meta["input"]["size"], n=1)
    presence = OnnxPoseEstimator(tmp_path / "mp.onnx").run(images, cams)[0][0]
    threshold = float(np.median(presence))  # about half the slots above it: some second slots without a first
    est = OnnxPoseEstimator(tmp_path / "mp.onnx", icp=None, averaging=False)
    est.threshold, est.min_visibility, est.score = threshold, 0.0, "p"
    ours = est.decode(*(o[0] for o in est.run(images, cams)))
    param = system.parameterization.with_decoding(threshold=threshold, min_visibility=0.0, score="p", averaging=False)
    with torch.no_grad():
        theirs = param.decode(system(torch.from_numpy(images)), [Camera(*cams[0][:4], int(cams[0][4]),
                                                                        int(cams[0][5]), *cams[0][6:])])[0]
    assert len(ours.t) < int((presence > threshold).sum())  # the rule removed some
    assert len(ours.t) == len(theirs.t)
    np.testing.assert_allclose(np.sort(ours.t, axis=0), np.sort(theirs.t, axis=0), atol=1e-5)

def _export_with_hypotheses(checkpoint: Path, out: Path) -> tuple[object, Path]:
    """The tiny checkpoint (2 training steps: presence ~ 0.05 everywhere) exported with threshold 0
    and averaging on, so every cell is a hypothesis and DBSCAN has work to do."""
    system, cfg = load_checkpoint(checkpoint)
    system.parameterization = system.parameterization.with_decoding(
        threshold=0.0, score="p*v", averaging={"eps": 0.5, "min_samples": 1, "cluster_score": "sum"})
    export_onnx(system, cfg, checkpoint, out)
    return system, out


def test_deployment_without_torch_gives_predict_hypotheses(checkpoint: Path, tiny_dataset: Path, tmp_path: Path) -> None:
    system, onnx_path = _export_with_hypotheses(checkpoint, tmp_path / "model.onnx")
    ds = IPADataset(tiny_dataset)
    records = [ds[i] for i in (2, 7, 13)]
    np.savez(tmp_path / "inputs.npz", **{f"depth{i}": r.depth for i, r in enumerate(records)},
             **{f"camera{i}": np.array([getattr(r.camera, k) for k in ("fx", "fy", "cx", "cy", "width", "height",
                                                                            "clip_start", "clip_end")])
                for i, r in enumerate(records)})
    script = f"""
import sys
sys.modules["torch"] = None  # any "import torch" now fails
import numpy as np
from opnet.deploy.runtime import OnnxPoseEstimator
from opnet.geometry.camera import Camera
est = OnnxPoseEstimator({str(onnx_path)!r})
data = np.load({str(tmp_path / 'inputs.npz')!r})
out = {{}}
for i in range({len(records)}):
    c = data[f"camera{{i}}"]
    h = est.predict(data[f"depth{{i}}"], Camera(*c[:4], int(c[4]), int(c[5]), *c[6:]))
    out.update({{f"R{{i}}": h.R, f"t{{i}}": h.t, f"s{{i}}": h.score}})
np.savez({str(tmp_path / 'out.npz')!r}, **out)
assert sys.modules["torch"] is None
print("torch-free ok")
"""
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=REPO_ROOT)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "torch-free ok" in proc.stdout
    got = np.load(tmp_path / "out.npz")
    space = system.parameterization.obj.pose_space
    for i, r in enumerate(records):
        net_in, net_cam = to_network_input(r.depth, r.camera, size=128, interpolation=cv2.INTER_AREA)
        with torch.no_grad():
            ref = system.parameterization.decode(system(torch.from_numpy(net_in)[None, None]), [net_cam])[0]
        assert len(ref) == len(got[f"s{i}"]) > 0
        order_ref, order_got = np.argsort(-ref.score, kind="stable"), np.argsort(-got[f"s{i}"], kind="stable")
        assert np.allclose(ref.score[order_ref], got[f"s{i}"][order_got], atol=1e-5)
        d = pose_distance(space, ref.R[order_ref], ref.t[order_ref], got[f"R{i}"][order_got], got[f"t{i}"][order_got])
        assert d.max() < 1e-4  # metres, symmetry-aware: 0.1 mm


def test_the_runtime_pools_the_turned_inputs_as_pytorch_does(checkpoint: Path, tiny_dataset: Path,
                                                            tmp_path: Path) -> None:
    """An export whose decoding pools four quarter turns: the runtime runs the graph on each turned input with
    its turned camera and gives the hypotheses PyTorch's decoding gives, which differ from one pass's."""
    system, cfg = load_checkpoint(checkpoint)
    system.parameterization = system.parameterization.with_decoding(
        threshold=0.0, score="p*v", averaging={"eps": 0.5, "min_samples": 1, "cluster_score": "sum"}, turns=4)
    export_onnx(system, cfg, checkpoint, tmp_path / "turns.onnx")
    est = OnnxPoseEstimator(tmp_path / "turns.onnx", icp=None)
    assert est.decoding.turns == 4
    space = system.parameterization.obj.pose_space
    for record in (IPADataset(tiny_dataset)[i] for i in (2, 7)):
        got = est.predict(record.depth, record.camera)
        net_in, net_cam = to_network_input(record.depth, record.camera, size=128, interpolation=cv2.INTER_AREA)
        x = torch.from_numpy(net_in)[None, None]
        with torch.no_grad():
            ref = system.decode(system(x), [net_cam], x)[0]
            alone = system.parameterization.with_decoding(turns=1).decode(system(x), [net_cam])[0]
        assert len(ref) == len(got) > 0
        assert (len(ref), round(float(ref.score.sum()), 6)) != (len(alone), round(float(alone.score.sum()), 6))
        # each of PyTorch's hypotheses is one of the runtime's: the same score and translation (ties in score make
        # an order by score differ between the two), and the same pose under the symmetry
        same = (abs(ref.score[:, None] - got.score[None]) < 1e-5) & (
            np.linalg.norm(ref.t[:, None] - got.t[None], axis=-1) < 1e-4)
        assert same.any(1).all() and same.any(0).all()
        i, j = np.nonzero(same)
        assert pose_distance(space, ref.R[i], ref.t[i], got.R[j], got.t[j]).min(initial=0.0) < 1e-4
        first = np.unique(i, return_index=True)[1]  # one match of each
        assert pose_distance(space, ref.R[i[first]], ref.t[i[first]], got.R[j[first]], got.t[j[first]]).max() < 1e-4


def test_numpy_pose_space_equals_the_metrics_torch_code() -> None:
    rng = np.random.default_rng(0)
    for name in ("zbracket", "shaft", "bracket"):
        space = builtin_object(name).pose_space
        q = rng.standard_normal((50, 4))
        from opnet.geometry.rotations import quaternion_to_matrix

        R = quaternion_to_matrix(q / np.linalg.norm(q, axis=1, keepdims=True))
        t = rng.normal(0, 0.05, (50, 3))
        ref = space.distance(torch.from_numpy(R[:25]), torch.from_numpy(t[:25]), torch.from_numpy(R[25:]),
                             torch.from_numpy(t[25:])).numpy()
        assert np.allclose(pose_distance(space, R[:25], t[:25], R[25:], t[25:]), ref, atol=1e-12)
        ref_eq = space.closest_equivalent(torch.from_numpy(R[:25]), torch.from_numpy(R[25:])).numpy()
        assert np.allclose(closest_equivalent(space, R[:25], R[25:]), ref_eq, atol=1e-12)


def test_export_entry_point_and_bad_input(checkpoint: Path, tmp_path: Path) -> None:
    out = tmp_path / "m.onnx"
    meta = export_cli.run(compose_cfg("export", [f"ckpt={checkpoint}", f"out={out}"]))
    assert out.stat().st_size > 10_000 and max(meta["max_abs_difference"].values()) < 1e-3
    with pytest.raises(ValueError, match=r"m\.onnx: exists already; pass overwrite=true"):
        export_cli.run(compose_cfg("export", [f"ckpt={checkpoint}", f"out={out}"]))
    with pytest.raises(ValueError, match=r"format='tflite': unknown export format; expected one of onnx"):
        export_cli.run(compose_cfg("export", [f"ckpt={checkpoint}", "format=tflite"]))
    with pytest.raises(ValueError, match=r"last\.ckpt: a checkpoint of the 'vanilla' parameterization, not 'eve'"):
        export_cli.run(compose_cfg("export", [f"ckpt={checkpoint}", f"out={tmp_path / 'x.onnx'}", "expect_parameterization=eve"]))
    other = tmp_path / "other.ckpt"  # another checkpoint, overwrite=true: never replaced by ONNX bytes
    other.write_bytes(checkpoint.read_bytes())
    with pytest.raises(ValueError, match=r"other\.ckpt: an ONNX export is written to a \.onnx file, not \.ckpt"):
        export_cli.run(compose_cfg("export", [f"ckpt={checkpoint}", f"out={other}", "overwrite=true"]))
    assert other.read_bytes() == checkpoint.read_bytes()
    not_ckpt = tmp_path / "notes.ckpt"
    not_ckpt.write_text("not a checkpoint")
    with pytest.raises(ValueError, match=r"notes\.ckpt: cannot read checkpoint"):
        export_cli.run(compose_cfg("export", [f"ckpt={not_ckpt}"]))
    with pytest.raises(FileNotFoundError, match=r"missing\.ckpt: checkpoint not found"):
        export_cli.run(compose_cfg("export", [f"ckpt={tmp_path / 'missing.ckpt'}"]))
    # the command line: one-line error, exit 2
    proc = subprocess.run([sys.executable, "export.py", f"ckpt={not_ckpt}"], cwd=REPO_ROOT, capture_output=True, text=True)
    assert proc.returncode == 2 and proc.stderr.strip().startswith("error:") and "notes.ckpt" in proc.stderr


def test_runtime_refuses_foreign_and_mismatched_models(checkpoint: Path, tmp_path: Path) -> None:
    import onnx

    out = tmp_path / "m.onnx"
    export_cli.run(compose_cfg("export", [f"ckpt={checkpoint}", f"out={out}", "check=false"]))
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"\x00garbage")
    with pytest.raises(ValueError, match=r"junk\.onnx: not a loadable ONNX model"):
        OnnxPoseEstimator(junk)
    proto = onnx.load(str(out))
    meta = json.loads(proto.metadata_props[0].value)
    # metadata claiming another parameterization layout than the graph decodes (MP: several slots)
    proto.metadata_props[0].value = json.dumps({**meta, "parameterization": "mp", "slots": 4})
    onnx.save(proto, str(tmp_path / "mismatch.onnx"))
    with pytest.raises(ValueError, match=r"mismatch\.onnx: the graph decodes 256 cells, but the metadata's mp"):
        OnnxPoseEstimator(tmp_path / "mismatch.onnx")
    # a NaN threshold used to be taken (the checkpoint path refuses it): validated the same way now
    proto.metadata_props[0].value = json.dumps({**meta, "decoding": {**meta["decoding"], "threshold": float("nan")}})
    onnx.save(proto, str(tmp_path / "nan.onnx"))
    with pytest.raises(ValueError, match=r"nan\.onnx: opnet metadata decoding\.threshold=nan: expected a number in \[0, 1\)$"):
        OnnxPoseEstimator(tmp_path / "nan.onnx")
    # ICP model points: one normal per point; a model exported without them cannot refine
    icp = meta["icp_model"]
    proto.metadata_props[0].value = json.dumps({**meta, "icp_model": {**icp, "normals": icp["normals"][:-1]}})
    onnx.save(proto, str(tmp_path / "icp.onnx"))
    with pytest.raises(ValueError, match=r"icp\.onnx: opnet metadata icp_model\.normals='599 normals': expected one per point \(600\)"):
        OnnxPoseEstimator(tmp_path / "icp.onnx")
    proto.metadata_props[0].value = json.dumps({**meta, "icp_model": None})
    onnx.save(proto, str(tmp_path / "no_icp.onnx"))
    OnnxPoseEstimator(tmp_path / "no_icp.onnx")  # fine without ICP
    with pytest.raises(ValueError, match=r"no_icp\.onnx: no ICP model points in its metadata"):
        OnnxPoseEstimator(tmp_path / "no_icp.onnx", icp=ICPSettings())
    # a recorded refinement that ranks on model points of its own (search_flat) needs them in the metadata
    proto.metadata_props[0].value = json.dumps({**meta, "refine": "search_flat"})
    onnx.save(proto, str(tmp_path / "flat.onnx"))
    with pytest.raises(ValueError, match=r"flat\.onnx: the refinement ranks on 2000 model points of its own"):
        OnnxPoseEstimator(tmp_path / "flat.onnx")
    ranked = {**icp, "rank_points": (icp["points"] * 4)[:2000], "rank_normals": (icp["normals"] * 4)[:2000]}
    proto.metadata_props[0].value = json.dumps({**meta, "refine": "search_flat", "icp_model": ranked})
    onnx.save(proto, str(tmp_path / "flat_ranked.onnx"))
    refiner = OnnxPoseEstimator(tmp_path / "flat_ranked.onnx").refiner  # with them: the ranking's own cloud
    assert len(refiner.rank_model.points) == 2000 and refiner.settings.search.rank_points == 2000
    with pytest.raises(ValueError, match=r"threads=20000: expected a whole number in 1\.\."):
        OnnxPoseEstimator(out, threads=20000)
    del proto.metadata_props[0]
    onnx.save(proto, str(tmp_path / "bare.onnx"))
    with pytest.raises(ValueError, match=r"bare\.onnx: no opnet metadata"):
        OnnxPoseEstimator(tmp_path / "bare.onnx")


def test_deploy_command_line_without_torch(checkpoint: Path, tiny_dataset: Path, tmp_path: Path) -> None:
    """``python -m opnet.deploy`` on a dataset folder, with torch unimportable: the outputs of
    predict.py (pose JSON, Siléane results), exit 0; bad arguments exit 2 with one line."""
    _, onnx_path = _export_with_hypotheses(checkpoint, tmp_path / "model.onnx")
    folder = tiny_dataset / "p_depth" / "cycle_0001"
    code = ("import sys; sys.modules['torch'] = None\n"
            "from opnet.deploy.__main__ import main\n"
            "sys.exit(main(sys.argv[1:]))")
    proc = subprocess.run([sys.executable, "-c", code, str(onnx_path), str(folder), "--out", str(tmp_path / "out")],
                          capture_output=True, text=True, cwd=REPO_ROOT)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    pngs = sorted(folder.glob("*.png"))
    assert f"{len(pngs)} of {len(pngs)} predictions written" in proc.stdout
    doc = json.loads((tmp_path / "out" / f"{pngs[-1].stem}.json").read_text())
    assert doc["object"] == "zbracket" and len(doc["poses"]) > 0
    assert len(list((tmp_path / "out" / "results").glob("*.json"))) == len(pngs)
    bad = subprocess.run([sys.executable, "-c", code, str(tmp_path / "none.onnx"), str(folder), "--out", str(tmp_path / "o2")],
                         capture_output=True, text=True, cwd=REPO_ROOT)
    assert bad.returncode == 2 and bad.stderr.strip() == f"error: {tmp_path / 'none.onnx'}: ONNX model not found"


def test_runtime_icp_refines_as_eval_does_from_the_exported_model_points(checkpoint: Path, tiny_dataset: Path,
                                                                         tmp_path: Path) -> None:
    from opnet.refine import Refiner

    system, onnx_path = _export_with_hypotheses(checkpoint, tmp_path / "model.onnx")
    settings = ICPSettings(budget_ms=None)
    plain, refined = OnnxPoseEstimator(onnx_path), OnnxPoseEstimator(onnx_path, icp=settings)
    refiner = Refiner.for_object(system.parameterization.obj, settings)  # the mesh's points, as eval.py uses
    record = IPADataset(tiny_dataset)[7]
    h0 = plain.predict(record.depth, record.camera)
    expected, status = refiner(h0, record.depth, record.camera)
    got = refined.predict(record.depth, record.camera)
    assert "refined" in status and not np.allclose(expected.t, h0.t)
    assert np.abs(got.t - expected.t).max() < 1e-5 and np.abs(got.R - expected.R).max() < 1e-4
    code = ("import sys; sys.modules['torch'] = None\n"
            "from opnet.deploy.__main__ import main\n"
            "sys.exit(main(sys.argv[1:]))")
    folder = tiny_dataset / "p_depth" / "cycle_0001"
    proc = subprocess.run([sys.executable, "-c", code, str(onnx_path), str(folder), "--out", str(tmp_path / "out"),
                           "--icp"], capture_output=True, text=True, cwd=REPO_ROOT)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    bad = subprocess.run([sys.executable, "-c", code, str(onnx_path), str(folder), "--out", str(tmp_path / "o2"),
                          "--icp-budget-ms", "5"], capture_output=True, text=True, cwd=REPO_ROOT)
    assert bad.returncode == 2 and bad.stderr.strip() == "error: --icp-budget-ms is a setting of --icp, --search or --search-fast, none is given"
    # the depth-agreement search: the runtime refines and re-scores as eval.py's refine=search does
    from opnet.refine import SearchSettings

    searching = ICPSettings(budget_ms=None, search=SearchSettings(turn_step_deg=30.0, shift=0.04))
    expected, status = Refiner.for_object(system.parameterization.obj, searching)(h0, record.depth, record.camera)
    got = OnnxPoseEstimator(onnx_path, icp=searching).predict(record.depth, record.camera)
    # a hypothesis the search turned onto another's pose is dropped as its duplicate ("suppressed"): how many
    # are depends on the model's exact outputs, which is not what this test is about
    assert set(status) <= {"searched", "no_depth", "suppressed"} and "searched" in status
    assert np.abs(got.t - expected.t).max() < 1e-5 and np.abs(got.score - expected.score).max() < 1e-6
    proc = subprocess.run([sys.executable, "-c", code, str(onnx_path), str(folder), "--out", str(tmp_path / "o3"),
                           "--search", "--icp-budget-ms", "50"], capture_output=True, text=True, cwd=REPO_ROOT)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    # without the exported averaging: the hypotheses of the checkpoint decoded with averaging off
    raw = OnnxPoseEstimator(onnx_path, averaging=False)
    assert raw.averaging is None and len(raw.predict(record.depth, record.camera).t) >= len(h0.t)
    bad = subprocess.run([sys.executable, "-c", code, str(onnx_path), str(folder), "--out", str(tmp_path / "o4"),
                          "--clip", "2", "1"], capture_output=True, text=True, cwd=REPO_ROOT)
    assert bad.returncode == 2 and bad.stderr.strip() == "error: --clip=[2.0, 1.0]: expected 0 < near < far <= 50 metres"


def test_a_quality_channel_exports_and_the_runtime_scores_with_it_as_pytorch_does(tmp_path: Path) -> None:
    """A network with a quality channel: the graph adds the output ``quality``, and the runtime's hypotheses
    scored p*v*q (four turns pooled, averaged) are PyTorch's; an export whose graph lacks the output but whose
    decoding reads it is refused, naming the file."""
    from opnet.geometry.camera import Camera

    cfg = compose_cfg("train", ["model=tiny", "object=zbracket", "parameterization=eve",
                                "parameterization.quality=true", "parameterization.score=p*v*q"])
    torch.manual_seed(0)
    system = build_components(cfg).system.eval()
    meta = assert_export_matches(system, cfg, tmp_path / "q.onnx")
    assert meta["outputs"][-1] == "quality" and meta["decoding"]["score"] == "p*v*q"
    images, cams = export_cli.synthetic_inputs(meta["input"]["size"], n=1)
    dense = OnnxPoseEstimator(tmp_path / "q.onnx").run(images, cams)
    with torch.no_grad():
        q_ref = system(torch.from_numpy(images))[:, system.parameterization.layout.quality].reshape(1, -1)
    np.testing.assert_allclose(dense[4], q_ref.numpy(), atol=1e-5)
    system.parameterization = system.parameterization.with_decoding(threshold=0.0, turns=4)
    export_onnx(system, cfg, Path("none.ckpt"), tmp_path / "q4.onnx")
    est = OnnxPoseEstimator(tmp_path / "q4.onnx", icp=None)
    dense = est.run(images, cams)
    assert len(dense) == 5 and dense[4].shape == dense[0].shape
    got = est.decode(*(o[0] for o in dense))
    camera = Camera(*cams[0][:4], int(cams[0][4]), int(cams[0][5]), *cams[0][6:])
    x = torch.from_numpy(images)
    with torch.no_grad():
        ref = system.decode(system(x), [camera], x)[0]
        plain = system.parameterization.with_decoding(score="p*v", turns=1).decode(system(x), [camera])[0]
    assert len(ref) == len(got) > 0
    np.testing.assert_allclose(np.sort(ref.score), np.sort(got.score), atol=1e-5)
    assert plain.score.max() > ref.score.max()  # q < 1 lowered the scores
    meta_only = dict(meta, outputs=meta["outputs"][:4])
    system_plain = build_components(compose_cfg("train", ["model=tiny", "object=zbracket",
                                                          "parameterization=eve"])).system.eval()
    export_onnx(system_plain, cfg, Path("none.ckpt"), tmp_path / "plain.onnx")
    import onnx

    proto = onnx.load(str(tmp_path / "plain.onnx"))
    entry = next(e for e in proto.metadata_props if e.key == "opnet")
    entry.value = json.dumps({**json.loads(entry.value), "decoding": meta_only["decoding"],
                              "outputs": meta_only["outputs"]})
    onnx.save(proto, str(tmp_path / "plain_q.onnx"))
    with pytest.raises(ValueError, match=r"plain_q.onnx: decoding.score='p\*v\*q' reads the quality channel q"):
        OnnxPoseEstimator(tmp_path / "plain_q.onnx")
