"""Inference latency of the paper network against this machine's compute ceiling.

    python scripts/bench/bench_infer.py [--model paper] [--batches 1,32] [--repeats 10] [--threads N]
                                  [--device cpu|cuda] [--compile] [--out results/speed/infer.csv]
                                  [--latency-out results/gpu/latency.csv] [--decoding tuned|paper]

In one run, per batch size: the preprocessing, the forward pass on each inference path (fp32
eager, fp32 channels-last, the default fused fp32 form, bf16 autocast channels-last, optionally
compiled) with its achieved GFLOP/s (the network's 9.97 GFLOP per image over the best time) and its
time as a multiple of the roofline floor, decoding + averaging, and end-to-end on the default path;
each of preprocessing, decoding + averaging and end-to-end also device-side (``inference.device_side``:
torch operations on the model's device, every image of the batch at once), timed interleaved with
its host counterpart (one call of each in turn, so a busy moment of the machine slows both).
The roofline is a 2048^2 fp32 matrix product's GFLOP/s, timed right before every repeat of every
forward (each warm: the second of two runs): each repeat's forward is divided by the floor of the
product timed beside it (the network's GFLOP at that moment's rate) and the median of those ratios
is the row's "x floor", so a slow moment of this shared machine slows both sides of a ratio
instead of skewing it.
then the same network exported to ONNX in ONNX Runtime (``--onnx``, default on when onnxruntime is
installed): the forward alone, and end-to-end on the torch-free deployment path
(:class:`opnet.deploy.runtime.OnnxPoseEstimator`: preprocess, graph with dense decoding,
threshold, averaging); then end-to-end / forward at batch 1 for every parameterization.

Input: a synthetic 512 x 512 bin-picking depth image with 5 % missing pixels (the preprocessing
crops it to the canvas, resizes to 128 x 128, fills holes, normalizes). Decoding turns a realistic
output (a perfect target of a 25-part scene plus noise, many low-confidence cells above tau) into
pose hypotheses. End-to-end = the three in sequence for one batch. On a CUDA device it also times
bf16 autocast, channels-last and a CUDA-graph replay of the forward pass, and the training
throughput of the paper network. Prints a table (milliseconds per batch and per image).

``--latency-out``: per batch and precision (fp32 = the default path of the device, bf16 autocast
channels-last, and on CUDA fp32 and bf16 forwards replayed as CUDA graphs), the forward and
end-to-end milliseconds per batch, end to end with the host's and with the device-side pre- and
postprocessing, and on CUDA at batch 1 the whole pipeline replayed as one graph
(:class:`opnet.inference.GraphedPipeline`, what ``predict.py`` runs on a GPU); columns device,
network, batch, precision, forward_ms, end_to_end_ms (the device's default: the one graph where the
row has it, else device-side on CUDA, host on the CPU), end_to_end_host_ms, end_to_end_device_ms,
end_to_end_graph_ms. Decoding: the parameterization with ``conf/decoding/<--decoding>.yaml``
(tuned: averaging on, as trained checkpoints decode).
"""

from __future__ import annotations

import argparse
import copy
import statistics
import time
import traceback
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import torch

from opnet.data import preprocess_torch
from opnet.data.preprocess import to_network_input
from opnet.geometry import Camera
from opnet.inference import CudaGraphForward, GraphedPipeline, InferenceSettings, fast_forward
from opnet.models.stats import gflops_per_image
from opnet.objects import builtin_object
from opnet.studies.scenes import depth_image, noisy_setup


def timeit(fn: Callable[[], object], repeats: int, sync: Callable[[], None] = lambda: None) -> tuple[float, float]:
    """(best, median) milliseconds of ``fn`` over ``repeats`` runs after two warm-up calls.

    The best of several runs is the one least disturbed by the rest of the machine (timeit's
    convention); the median is printed beside it.
    """
    for _ in range(2):
        fn()
    sync()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        sync()
        times.append(1000 * (time.perf_counter() - t0))
    return min(times), statistics.median(times)


def interleaved(fns: dict[str, Callable[[], object]], repeats: int,
                sync: Callable[[], None] = lambda: None) -> dict[str, tuple[float, float]]:
    """(best, median) milliseconds of each function, called in turn: every repeat runs each once,
    starting with the next one each time, so no arm owns the machine's quiet or busy moments."""
    names = list(fns)
    for name in names * 2:  # warm-up
        fns[name]()
    sync()
    times: dict[str, list[float]] = {name: [] for name in names}
    for r in range(repeats):
        for name in names[r % len(names):] + names[: r % len(names)]:
            t0 = time.perf_counter()
            fns[name]()
            sync()
            times[name].append(1000 * (time.perf_counter() - t0))
    return {name: (min(t), statistics.median(t)) for name, t in times.items()}


def paired_with_roofline(fn: Callable[[], object], repeats: int, gflop: float, device: torch.device,
                         sync: Callable[[], None] = lambda: None) -> tuple[float, float, float, list[float]]:
    """(best ms, median ms, median of forward / floor, the roofline GFLOP/s of each repeat).

    Every repeat runs a 2048^2 fp32 matrix product twice and ``fn`` (``gflop`` GFLOP) twice, back
    to back, and times the second of each: both warm in the caches, measured within a second of
    each other. The floor of a repeat is ``gflop`` at its product's rate.
    """
    a, b = torch.randn(2048, 2048, device=device), torch.randn(2048, 2048, device=device)

    def second(f: Callable[[], object]) -> float:
        f()
        sync()
        t0 = time.perf_counter()
        f()
        sync()
        return time.perf_counter() - t0

    fn()
    times, ratios, rates = [], [], []
    for _ in range(repeats):
        rates.append(2 * 2048**3 / second(lambda: a @ b) / 1e9)
        times.append(1000 * second(fn))
        ratios.append(times[-1] / 1000 / (gflop / rates[-1]))
    return min(times), statistics.median(times), statistics.median(ratios), rates


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default="paper", help="conf/model preset")
    ap.add_argument("--parameterization", default="vanilla", help="conf/parameterization option of the forward rows")
    ap.add_argument("--parameterizations", default="vanilla,eve,ap,z,mp,si",
                    help="end-to-end (fast default path, batch 1) for each of these")
    ap.add_argument("--object", default="zbracket", help="built-in object")
    ap.add_argument("--batches", default="1,32")
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--compile", action="store_true", help="also time torch.compile'd forwards (slow to start)")
    ap.add_argument("--out", type=Path, help="write the rows to this CSV (replaced)")
    ap.add_argument("--no-onnx", action="store_true", help="skip the ONNX Runtime rows")
    ap.add_argument("--decoding", default="tuned", help="conf/decoding option of every parameterization")
    ap.add_argument("--latency-out", type=Path, help="write the latency rows (forward and end to end per batch and "
                    "precision) to this CSV (replaced)")
    args = ap.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    device = torch.device(args.device)
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    rng = np.random.default_rng(0)
    obj = builtin_object(args.object)
    camera = Camera.from_fov(50.0, 512, 512, 0.6, 1.2)
    net_cam = to_network_input(np.full((512, 512), 1.0, np.float32), camera)[1]
    roofs: list[float] = []
    param, model, noisy = noisy_setup(args.parameterization, args.model, obj, net_cam, device, args.decoding)
    gflop = gflops_per_image(model)
    print(f"model {args.model} ({sum(p.numel() for p in model.parameters()) / 1e6:.3f} M params, {gflop:.2f} GFLOP "
          f"per image), device {device}, torch {torch.__version__}, {torch.get_num_threads()} threads")
    print(f"{'batch':>5} {'stage':<38} {'ms/batch':>9} {'ms/image':>9} {'median':>9} {'GFLOP/s':>8} {'x floor':>8}")
    rows: list[tuple[int, str, float, float, float | None, float | None]] = []

    def record(b: int, name: str, times: tuple[float, float]) -> None:
        ms, median = times
        rows.append((b, name, ms, median, None, None))
        print(f"{b:>5} {name:<38} {ms:>9.2f} {ms / b:>9.2f} {median / b:>9.2f}", flush=True)

    def record_forward(b: int, name: str, fn: Callable[[], object], repeats: int) -> None:
        best, median, x_floor, rates = paired_with_roofline(fn, repeats, gflop * b, device, sync)
        roofs.extend(rates)
        rate = gflop * b / (best / 1000)
        rows.append((b, name, best, median, rate, x_floor))
        print(f"{b:>5} {name:<38} {best:>9.2f} {best / b:>9.2f} {median / b:>9.2f} {rate:>8.1f} {x_floor:>8.3f}",
              flush=True)

    fast = InferenceSettings()  # the default of predict.py / eval.py: the fused fp32 form on the CPU
    onnx = None if args.no_onnx or device.type != "cpu" else onnx_paths(model, param)
    variants = forward_variants(device, model, args.compile)
    latency: list[LatencyRow] = []
    for b in [int(x) for x in args.batches.split(",")]:
        depths = [depth_image(camera, rng) for _ in range(b)]
        pre = lambda: [to_network_input(d, camera, 128, cv2.INTER_AREA) for d in depths]  # noqa: E731
        x = torch.from_numpy(np.stack([p[0] for p in pre()]))[:, None].to(device)
        out = noisy.expand(b, -1, -1, -1).contiguous().to(device)
        cams = [net_cam] * b
        arms = interleaved({"preprocess": pre, "preprocess (device-side)": lambda: preprocess_torch.to_network_input(
            depths, camera, 128, device=device)}, args.repeats, sync)  # fmt: skip
        for name, times in arms.items():
            record(b, name, times)
        for name, make in variants.items():
            record_forward(b, name, make(copy.deepcopy(model), x), args.repeats if b == 1 else max(3, args.repeats // 3))
        arms = interleaved({"decode + averaging": lambda: param.decode(out, cams),
                            "decode + averaging (device-side)": lambda: param.decode(out, cams, device_side=True)},
                           args.repeats, sync)  # fmt: skip
        for name, times in arms.items():
            record(b, name, times)
        run = fast_forward(copy.deepcopy(model), fast)
        on_device = fast.on_device(device)
        arms = interleaved({f"end-to-end ({'host pre/post' if on_device else 'default path'})": pipeline(
            param, run, depths, camera, net_cam, device, False), f"end-to-end ({'default path, ' if on_device else ''}"
            "device-side)": pipeline(param, run, depths, camera, net_cam, device, True)},
            args.repeats if b == 1 else 3, sync)  # fmt: skip
        for name, times in arms.items():
            record(b, name, times)
        if args.latency_out is not None:
            latency += latency_rows(model, param, depths, camera, net_cam, x, device, b,
                                    args.repeats if b == 1 else 3, sync)  # fmt: skip
        if onnx is not None:
            forward, estimator = onnx
            xn = x.cpu().numpy()
            record_forward(b, "forward ONNX Runtime fp32", lambda: forward(xn), args.repeats if b == 1 else 3)
            record(b, "end-to-end ONNX Runtime (no torch)",
                   timeit(lambda: estimator.predict_batch(depths, [camera] * b), args.repeats if b == 1 else 3))
    e2e_rows = []
    for name in [p for p in args.parameterizations.split(",") if p]:
        p_param, p_model, _ = noisy_setup(name, args.model, obj, net_cam, device, args.decoding)
        run = fast_forward(p_model, fast)
        depth = depth_image(camera, rng)

        def e2e() -> object:
            xs = torch.from_numpy(to_network_input(depth, camera, 128, cv2.INTER_AREA)[0])[None, None].to(device)
            return p_param.decode(run(xs), [net_cam])

        ms = timeit(e2e, args.repeats, sync)[0]
        fwd = timeit(lambda: run(torch.rand(1, 1, 128, 128, device=device)), args.repeats, sync)[0]
        e2e_rows.append((name, ms, fwd))
        print(f"    end-to-end {name:<8} batch 1: {ms:7.2f} ms, forward {fwd:7.2f} ms, ratio {ms / fwd:.3f}", flush=True)
    roof = statistics.median(roofs)
    print(f"\nroofline: 2048^2 fp32 matmul beside every forward repeat: median {roof:.1f} GFLOP/s (range "
          f"{min(roofs):.1f}-{max(roofs):.1f}, {len(roofs)} products) -> floor {1000 * gflop / roof:.1f} ms per image")
    print(f"{'batch':>5} {'stage':<38} {'ms/image':>9} {'median':>9} {'GFLOP/s':>8} {'x floor':>8}")
    for b, n, ms, med, r, xf in rows:
        if r:
            print(f"{b:>5} {n:<38} {ms / b:>9.2f} {med / b:>9.2f} {r:>8.1f} {xf:>8.3f}")
    if args.out is not None:
        span = f"{min(roofs):.1f}-{max(roofs):.1f}"
        lines = ["batch,stage,ms_batch,ms_image,ms_image_median,gflops_per_s,x_floor,roofline_gflops,forward_gflop,"
                 "roofline_range"]
        lines += [f"{b},{n},{ms:.2f},{ms / b:.2f},{med / b:.2f},{'' if r is None else f'{r:.1f}'},"
                  f"{'' if xf is None else f'{xf:.3f}'},{roof:.1f},{gflop:.3f},{span}" for b, n, ms, med, r, xf in rows]
        lines += [f"1,end-to-end {n} / forward,{ms:.2f},{ms:.2f},,,{ms / f:.3f},{roof:.1f},{gflop:.3f},{span}"
                  for n, ms, f in e2e_rows]
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text("\n".join(lines) + "\n")
    if args.latency_out is not None:
        write_latency(args.latency_out, device, args.model, latency)
    if device.type == "cuda":
        print(f"training throughput (bf16, batch 32): {train_throughput(model, param.out_channels, device):.1f} images/s")


def pipeline(param: object, run: Callable[[torch.Tensor], torch.Tensor], depths: list[np.ndarray], camera: Camera,
             net_cam: Camera, device: torch.device, on_device: bool) -> Callable[[], object]:  # fmt: skip
    """End to end as predict.py runs it for a batch of ``depths``: preprocessing, ``run``, decoding
    and averaging, on the host (OpenCV / numpy, image by image) or ``on_device`` (torch, the batch at once)."""
    cams = [net_cam] * len(depths)

    def call() -> object:
        if on_device:
            x = preprocess_torch.to_network_input(depths, camera, 128, device=device)[0]
        else:
            x = torch.from_numpy(np.stack([to_network_input(d, camera, 128, cv2.INTER_AREA)[0] for d in depths]))
        return param.decode(run(x[:, None] if x.dim() == 3 else x), cams, device_side=on_device)

    return call


#: the precisions of the latency rows: (name, settings, CUDA only)
LATENCY_PRECISIONS = (("fp32", InferenceSettings(cuda_graph=False), False),
                      ("bf16", InferenceSettings("bf16", True, cuda_graph=False), False),
                      ("fp32 CUDA graph", InferenceSettings("32", True, cuda_graph=True), True),
                      ("bf16 CUDA graph", InferenceSettings("bf16", True, cuda_graph=True), True))

#: a latency row: batch, precision, forward ms, end to end ms (host pre/post, device-side, whole
#: pipeline as one CUDA graph at batch 1 or None)
LatencyRow = tuple[int, str, float, float, float, float | None]


def latency_rows(model: torch.nn.Module, param: object, depths: list[np.ndarray], camera: Camera, net_cam: Camera,
                 x: torch.Tensor, device: torch.device, batch: int, repeats: int,
                 sync: Callable[[], None]) -> list[LatencyRow]:  # fmt: skip
    """The rows per precision of :data:`LATENCY_PRECISIONS` (the CUDA graph: every batch size
    captured, one graph each; at batch 1 also the whole pipeline as one graph,
    :class:`opnet.inference.GraphedPipeline`, which ``predict.py`` runs on a GPU)."""
    rows = []
    for name, settings, cuda_only in LATENCY_PRECISIONS:
        if cuda_only and device.type != "cuda":
            continue
        run = fast_forward(copy.deepcopy(model), settings)
        arms = {}
        if settings.cuda_graph is True:  # fast_forward graphs batch 1 only: here every batch size is one graph
            graph = CudaGraphForward(fast_forward(copy.deepcopy(model), replace(settings, cuda_graph=False)))
            run = torch.inference_mode()(lambda images, graph=graph: graph(images.to(device)))
            if batch == 1:
                whole = GraphedPipeline(copy.deepcopy(model), settings, param, camera, 128)
                try:  # captured here: a failure leaves the other rows standing
                    whole(depths[0])
                    arms["graph"] = lambda whole=whole: whole(depths[0])
                except Exception:  # noqa: BLE001 - printed, the row says so
                    traceback.print_exc()
                    print(f"    latency {name}: the whole pipeline could not be captured as one graph", flush=True)
        arms = {"forward": lambda run=run: run(x),
                "host": pipeline(param, run, depths, camera, net_cam, device, False),
                "device": pipeline(param, run, depths, camera, net_cam, device, True), **arms}
        times = interleaved(arms, repeats, sync)
        graphed = times["graph"][0] if "graph" in times else None
        rows.append((batch, name, times["forward"][0], times["host"][0], times["device"][0], graphed))
        print(f"    latency batch {batch:>3} {name:<16} forward {times['forward'][0]:8.2f} ms, end to end host "
              f"{times['host'][0]:8.2f} ms, device-side {times['device'][0]:8.2f} ms"
              + ("" if graphed is None else f", one graph {graphed:8.2f} ms"), flush=True)
    return rows


def write_latency(path: Path, device: torch.device, network: str, rows: list[LatencyRow]) -> None:
    """The latency CSV (replaced): end_to_end_ms is the device's default path (on CUDA the whole
    pipeline as one graph at batch 1 where the row has it, else device-side pre- and postprocessing;
    on the CPU the host's)."""
    default_on_device = InferenceSettings().on_device(device)
    lines = [("device,network,batch,precision,forward_ms,end_to_end_ms,end_to_end_host_ms,end_to_end_device_ms,"
              "end_to_end_graph_ms")]
    name = torch.cuda.get_device_name(device) if device.type == "cuda" else "cpu"
    for b, p, f, h, d, g in rows:
        default = g if g is not None else (d if default_on_device else h)
        lines.append(f"{name},{network},{b},{p},{f:.3f},{default:.3f},{h:.3f},{d:.3f},{'' if g is None else f'{g:.3f}'}")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")


def onnx_paths(model: torch.nn.Module, param: object) -> tuple[Callable[[np.ndarray], object], object] | None:
    """(forward of the network alone in ONNX Runtime, the torch-free estimator of the whole
    pipeline), both exported from ``model`` into a temporary folder; None without onnxruntime."""
    import tempfile
    import types

    try:
        import onnxruntime as ort
    except ImportError:
        print("onnxruntime not installed: no ONNX rows")
        return None
    from opnet.deploy.export import export_onnx
    from opnet.deploy.runtime import OnnxPoseEstimator
    from opnet.models.fused import export_form
    from opnet.run_settings import DecodingSettings, InputSettings, RunSettings

    folder = Path(tempfile.mkdtemp(prefix="opnet_bench_onnx_"))
    net = folder / "network.onnx"
    with torch.no_grad():  # the network as export.py traces it
        torch.onnx.export(export_form(model.cpu().eval()), torch.rand(1, 1, 128, 128), str(net), input_names=["x"],
                          dynamic_axes={"x": {0: "batch"}}, opset_version=17, dynamo=False)
    session = ort.InferenceSession(str(net), providers=["CPUExecutionProvider"])
    # the typed settings export_onnx reads (RunSettings): the network's input, the parameterization's decoding
    settings = RunSettings(InputSettings(size=getattr(model, "in_size", 128)), DecodingSettings.of(param))
    system = types.SimpleNamespace(backbone=model, parameterization=param, settings=settings)
    export_onnx(system, {}, Path("bench"), folder / "pipeline.onnx")
    return (lambda x: session.run(None, {"x": x})), OnnxPoseEstimator(folder / "pipeline.onnx")


#: builds, from a network (a copy of its own) and an input batch on the device, the call to time
Variant = Callable[[torch.nn.Module, torch.Tensor], Callable[[], object]]


def forward_variants(device: torch.device, model: torch.nn.Module, compile: bool = False) -> dict[str, Variant]:
    """The forward rows timed on ``device`` by name, in table order (nothing is built or run here):
    the inference paths of :func:`opnet.inference.fast_forward`, then on a CUDA device
    :data:`CUDA_VARIANTS` (bf16 autocast, channels-last and a CUDA-graph replay)."""
    fast = InferenceSettings(cuda_graph=False)  # the rows time the forward itself; the graph has its own row
    paths = {"forward fp32 eager": InferenceSettings("32", False, fused=False, cuda_graph=False),
             "forward fp32 channels-last": InferenceSettings("32", True, fused=False, cuda_graph=False),
             f"forward {fast.describe(device, model).split(',')[0]} (default)": fast,
             "forward bf16 autocast channels-last": InferenceSettings("bf16", True, cuda_graph=False)}
    if compile:
        paths["forward bf16 channels-last compiled"] = InferenceSettings("bf16", True, compile=True)
    variants: dict[str, Variant] = {name: _inference_path(settings) for name, settings in paths.items()}
    if device.type == "cuda":
        variants.update(CUDA_VARIANTS)
    return variants


def _inference_path(settings: InferenceSettings) -> Variant:
    def make(model: torch.nn.Module, x: torch.Tensor) -> Callable[[], object]:
        run = fast_forward(model, settings)
        return lambda: run(x)

    return make


def _bf16() -> torch.autocast:
    """bf16 autocast on CUDA; no weight cache, which a CUDA-graph capture must not use."""
    return torch.autocast("cuda", dtype=torch.bfloat16, cache_enabled=False)


def cuda_bf16(model: torch.nn.Module, x: torch.Tensor) -> Callable[[], object]:
    """The network as it is (contiguous) under bf16 autocast."""
    model.eval()

    def run() -> object:
        with torch.inference_mode(), _bf16():
            return model(x)

    return run


def cuda_bf16_channels_last(model: torch.nn.Module, x: torch.Tensor) -> Callable[[], object]:
    """Channels-last weights and input under bf16 autocast, one call for the whole batch."""
    model.eval().to(memory_format=torch.channels_last)
    xc = x.contiguous(memory_format=torch.channels_last)

    def run() -> object:
        with torch.inference_mode(), _bf16():
            return model(xc)

    return run


def cuda_graph(model: torch.nn.Module, x: torch.Tensor) -> Callable[[], object]:
    """A CUDA graph of the bf16 channels-last forward of ``x`` (captured after three warm-up calls
    on a side stream), replayed: one launch instead of one per kernel."""
    model.eval().to(memory_format=torch.channels_last)
    static_in = x.contiguous(memory_format=torch.channels_last).clone()
    side = torch.cuda.Stream()
    side.wait_stream(torch.cuda.current_stream())
    with torch.cuda.stream(side), torch.inference_mode(), _bf16():
        for _ in range(3):
            model(static_in)
    torch.cuda.current_stream().wait_stream(side)
    graph = torch.cuda.CUDAGraph()
    with torch.cuda.graph(graph), torch.inference_mode(), _bf16():
        model(static_in)
    return graph.replay


#: the forward rows only a CUDA device has
CUDA_VARIANTS: dict[str, Variant] = {"forward bf16": cuda_bf16, "forward bf16 channels-last": cuda_bf16_channels_last,
                                     "forward bf16 CUDA graph": cuda_graph}


def train_throughput(model: torch.nn.Module, channels: int, device: torch.device, batch: int = 32, steps: int = 20) -> float:
    model.train()
    opt = torch.optim.AdamW(model.parameters(), 1e-3)
    x = torch.rand(batch, 1, 128, 128, device=device).to(memory_format=torch.channels_last)
    y = torch.rand(batch, channels, 16, 16, device=device)

    def step() -> None:
        with torch.autocast("cuda", dtype=torch.bfloat16):
            loss = (model(x).float() - y).square().mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()

    ms = timeit(step, steps, torch.cuda.synchronize)[1]
    return batch * 1000 / ms


if __name__ == "__main__":
    main()
