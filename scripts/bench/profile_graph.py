"""Where the time of one image goes on the whole-image CUDA graph (:class:`opnet.inference.GraphedPipeline`).

    python scripts/bench/profile_graph.py [--model paper] [--parameterization vanilla] [--repeats 50]
                                    [--out results/gpu/graph_profile.csv]

On a CUDA device, the paper network with random weights on a synthetic 512 x 512 depth image (as
``scripts/bench/bench_infer.py``), bf16 and fp32: the whole pipeline end to end (best and median of
``--repeats`` after warm-up), then its parts, each timed alone the same way: the host's copy of the
depth into the pinned buffer and on to the device; the replay of the one graph (synchronized); the
table's copy back; the host's finish (rows ordered, rotations projected); and, each captured as a
graph of its own, the preprocessing, the network and the decoding with averaging (GPU time by CUDA
events), the decoding also without averaging. Prints a table; writes the rows to ``--out``.
"""

from __future__ import annotations

import argparse
import copy
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from opnet.data import preprocess_torch
from opnet.data.preprocess import to_network_input
from opnet.geometry import Camera
from opnet.inference import GraphedPipeline, InferenceSettings, capture_graph
from opnet.objects import builtin_object
from opnet.studies.scenes import depth_image, noisy_setup


def host_ms(fn: Callable[[], object], repeats: int) -> tuple[float, float]:
    """(best, median) wall milliseconds of ``fn`` (which synchronizes itself) after 5 warm-up calls."""
    for _ in range(5):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(1000 * (time.perf_counter() - t0))
    return min(times), statistics.median(times)


def graph_ms(fn: Callable[[], object], repeats: int) -> tuple[float, float]:
    """(best, median) GPU milliseconds of ``fn`` captured as a CUDA graph of its own (CUDA events)."""
    with torch.no_grad():  # as GraphedPipeline.compute (compiled code: no inference mode)
        graph, _ = capture_graph(fn, torch.device("cuda"))
    times = []
    for r in range(repeats + 5):
        start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
        start.record()
        graph.replay()
        end.record()
        end.synchronize()
        if r >= 5:
            times.append(start.elapsed_time(end))
    return min(times), statistics.median(times)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default="paper")
    ap.add_argument("--parameterization", default="vanilla")
    ap.add_argument("--object", default="zbracket")
    ap.add_argument("--repeats", type=int, default=50)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--fuse", action="store_true",
                    help="also bf16 with the preprocessing and decoding compiled (GraphedPipeline(fuse=True))")
    args = ap.parse_args(argv)
    if not torch.cuda.is_available():
        sys.exit("profile_graph.py: no CUDA device (the graph runs on a GPU only)")
    device = torch.device("cuda")
    camera = Camera.from_fov(50.0, 512, 512, 0.6, 1.2)
    net_cam = to_network_input(np.full((512, 512), 1.0, np.float32), camera)[1]
    param, model, _ = noisy_setup(args.parameterization, args.model, builtin_object(args.object), net_cam, device, "tuned")
    depth = depth_image(camera, np.random.default_rng(0))
    name = torch.cuda.get_device_name()
    rows: list[tuple[str, str, float, float]] = []

    def record(precision: str, stage: str, times: tuple[float, float]) -> None:
        rows.append((precision, stage, *times))
        print(f"{precision:<5} {stage:<44} {times[0]:8.3f} {times[1]:8.3f} ms", flush=True)

    print(f"{name}, torch {torch.__version__}, model {args.model}, {args.parameterization}, tuned decoding")
    print(f"{'':<5} {'stage':<44} {'best':>8} {'median':>8}")
    for precision in ("bf16", "32"):
        settings = InferenceSettings(precision, True, cuda_graph=True)
        pipe = GraphedPipeline(copy.deepcopy(model), settings, param, camera, 128)
        record(precision, "end to end (one graph)", host_ms(lambda pipe=pipe: pipe(depth), args.repeats))
        hyps = pipe(depth)
        record(precision, "  copy in (pinned, to the device)", host_ms(lambda pipe=pipe: (
            pipe._host_depth[0].numpy().__setitem__(Ellipsis, depth), pipe._depth.copy_(pipe._host_depth, non_blocking=True),
            torch.cuda.synchronize()), args.repeats))  # fmt: skip
        record(precision, "  replay (synchronized)", host_ms(lambda pipe=pipe: (pipe._graph.replay(), torch.cuda.synchronize()),
                                                            args.repeats))  # fmt: skip
        record(precision, "  copy out (the table)", host_ms(lambda pipe=pipe: (
            pipe._host_result.copy_(pipe._result, non_blocking=True), torch.cuda.synchronize()), args.repeats))
        values = pipe._host_result.numpy()
        table = values[:-3].reshape(1, pipe.decoding.cells, -1)
        record(precision, "  host finish (order, SO(3) projection)", host_ms(
            lambda pipe=pipe, table=table: pipe.decoding.hypotheses(table, np.array([True]), pipe._output), args.repeats))
        # the parts as graphs of their own: GPU time
        x = preprocess_torch.to_network_input(pipe._depth, camera, 128, canvas=pipe.canvas, static=True)[0]
        out = pipe.forward(x)
        record(precision, "  GPU: preprocessing", graph_ms(lambda pipe=pipe: preprocess_torch.to_network_input(
            pipe._depth, camera, 128, canvas=pipe.canvas, static=True), args.repeats))  # fmt: skip
        record(precision, "  GPU: network", graph_ms(lambda pipe=pipe, x=x: pipe.forward(x), args.repeats))
        record(precision, "  GPU: decoding + averaging", graph_ms(lambda pipe=pipe, out=out: pipe.decoding(out),
                                                                  args.repeats))  # fmt: skip
        plain = type(pipe.decoding)(param.with_decoding(averaging=False), pipe.net_camera, 1, device)
        record(precision, "  GPU: decoding without averaging", graph_ms(lambda plain=plain, out=out: plain(out),
                                                                        args.repeats))  # fmt: skip
        record(precision, "  GPU: the whole graph", graph_ms(lambda pipe=pipe: pipe.compute(pipe._depth), args.repeats))
        print(f"      ({len(hyps)} hypotheses, {pipe.decoding.cells} cells)")
    if args.fuse:  # the same pipeline, its preprocessing and decoding compiled
        settings = InferenceSettings("bf16", True, cuda_graph=True)
        plain = GraphedPipeline(copy.deepcopy(model), settings, param, camera, 128)
        t0 = time.perf_counter()
        fused = GraphedPipeline(copy.deepcopy(model), settings, param, camera, 128, fuse=True)
        first = fused(depth)
        print(f"      fused: compiled and captured in {time.perf_counter() - t0:.1f} s")
        same = plain(depth)
        worst = max(np.abs(first.t - same.t).max(initial=0), np.abs(first.R - same.R).max(initial=0)) \
            if len(first) == len(same) else float("inf")
        print(f"      fused against unfused: {len(first)} / {len(same)} hypotheses, largest difference {worst:.2e}")
        times = {"plain": [], "fused": []}
        for _ in range(5):
            plain(depth), fused(depth)
        for r in range(2 * args.repeats):  # interleaved
            for key in (("plain", "fused") if r % 2 else ("fused", "plain")):
                t0 = time.perf_counter()
                (plain if key == "plain" else fused)(depth)
                times[key].append(1000 * (time.perf_counter() - t0))
        for key in ("plain", "fused"):
            record("bf16", f"end to end (one graph{', fused' if key == 'fused' else ''}, interleaved)",
                   (min(times[key]), statistics.median(times[key])))
        record("bf16", "  GPU: the whole graph, fused", graph_ms(lambda: fused.compute(fused._depth), args.repeats))
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        lines = ["device,network,parameterization,precision,stage,best_ms,median_ms"]
        lines += [f"{name},{args.model},{args.parameterization},{p},{s.strip()},{b:.4f},{m:.4f}" for p, s, b, m in rows]
        args.out.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
