"""Inference latency of the paper network: preprocessing, forward pass and decoding, timed apart.

    python scripts/bench_infer.py [--model paper] [--parameterization vanilla] [--batches 1,32]
                                  [--repeats 10] [--threads N] [--device cpu|cuda]

Input: a synthetic 512 x 512 bin-picking depth image with 5 % missing pixels (the preprocessing
crops it to the canvas, resizes to 128 x 128, fills holes, normalizes). Decoding turns a realistic
output (a perfect target of a 25-part scene plus noise, many low-confidence cells above tau) into
pose hypotheses. End-to-end = the three in sequence for one batch. On a CUDA device it also times
bf16 autocast, channels-last and a CUDA-graph replay of the forward pass, and the training
throughput of the paper network. Prints a table (milliseconds per batch and per image).
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import cv2
import numpy as np
import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf

from opnet.data.preprocess import to_network_input
from opnet.geometry import Camera
from opnet.objects import builtin_object
from opnet.parameterizations.toy_scenes import random_scene_batch
from opnet.paths import config_dir


def timeit(fn: Callable[[], object], repeats: int, sync: Callable[[], None] = lambda: None) -> float:
    """Median milliseconds of ``fn`` over ``repeats`` runs after two warm-up calls."""
    for _ in range(2):
        fn()
    sync()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        sync()
        times.append(1000 * (time.perf_counter() - t0))
    return statistics.median(times)


def depth_image(camera: Camera, rng: np.random.Generator) -> np.ndarray:
    """A bin floor with box-shaped parts on it and 5 % missing pixels, metres."""
    depth = np.full((camera.height, camera.width), 0.9 * camera.clip_end, np.float32)
    for _ in range(25):
        x, y = rng.integers(0, camera.width - 60), rng.integers(0, camera.height - 60)
        depth[y : y + rng.integers(20, 60), x : x + rng.integers(20, 60)] -= rng.uniform(0.02, 0.1)
    depth[rng.random(depth.shape) < 0.05] = np.nan
    return depth


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default="paper", help="conf/model preset")
    ap.add_argument("--parameterization", default="vanilla", help="conf/parameterization option")
    ap.add_argument("--object", default="zbracket", help="built-in object")
    ap.add_argument("--batches", default="1,32")
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    device = torch.device(args.device)
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    rng = np.random.default_rng(0)

    obj = builtin_object(args.object)
    pcfg = OmegaConf.load(config_dir() / "parameterization" / f"{args.parameterization}.yaml")
    param = instantiate(pcfg, _partial_=True)(obj=obj)
    model = instantiate(OmegaConf.load(config_dir() / "model" / f"{args.model}.yaml"),
                        out_channels=param.out_channels, out_grid=param.grid_size).to(device).eval()
    camera = Camera.from_fov(50.0, 512, 512, 0.6, 1.2)
    net_cam = to_network_input(np.full((512, 512), 1.0, np.float32), camera)[1]
    gt = random_scene_batch(obj, net_cam, 1, 25, torch.Generator().manual_seed(0))
    perfect = param.encode(gt, net_cam)
    noisy = (perfect + 0.01 * torch.rand_like(perfect)).clamp(0, 1)
    presence = noisy[:, :: param.channels_per_slot]
    presence[torch.rand_like(presence) < 0.15] = 0.2  # low-confidence cells above tau

    print(f"model {args.model} ({sum(p.numel() for p in model.parameters()) / 1e6:.3f} M params), "
          f"parameterization {args.parameterization}, device {device}, torch threads {torch.get_num_threads()}")
    print(f"{'batch':>5} {'stage':<28} {'ms/batch':>10} {'ms/image':>10}")
    rows = []
    for b in [int(x) for x in args.batches.split(",")]:
        depths = [depth_image(camera, rng) for _ in range(b)]
        pre = lambda: [to_network_input(d, camera, 128, cv2.INTER_AREA) for d in depths]  # noqa: E731
        x = torch.from_numpy(np.stack([p[0] for p in pre()]))[:, None].to(device)
        out = noisy.expand(b, -1, -1, -1).contiguous().to(device)
        cams = [net_cam] * b

        def forward() -> torch.Tensor:
            with torch.inference_mode():
                return model(x)

        def decode() -> object:
            return param.decode(out, cams)

        def end_to_end() -> object:
            xs = torch.from_numpy(np.stack([p[0] for p in pre()]))[:, None].to(device)
            with torch.inference_mode():
                y = model(xs)
            return param.decode(y.float(), cams)

        stages = {"preprocess": pre, "forward (fp32)": forward, "decode + averaging": decode}
        if device.type == "cuda":
            stages.update(cuda_variants(model, x))
        stages["end-to-end"] = end_to_end
        for name, fn in stages.items():
            ms = timeit(fn, args.repeats, sync)
            rows.append((b, name, ms))
            print(f"{b:>5} {name:<28} {ms:>10.2f} {ms / b:>10.2f}")
        fwd = next(ms for bb, n, ms in rows if bb == b and n == "forward (fp32)")
        e2e = next(ms for bb, n, ms in rows if bb == b and n == "end-to-end")
        print(f"{b:>5} {'end-to-end / forward':<28} {e2e / fwd:>10.3f}")
    if device.type == "cuda":
        print(f"training throughput (bf16, batch 32): {train_throughput(model, param.out_channels, device):.1f} images/s")


def cuda_variants(model: torch.nn.Module, x: torch.Tensor) -> dict[str, Callable[[], object]]:
    """bf16 autocast, channels-last + bf16, and a CUDA graph of the bf16 channels-last forward."""
    cl = model.to(memory_format=torch.channels_last)
    xc = x.to(memory_format=torch.channels_last)

    def bf16() -> object:
        with torch.inference_mode(), torch.autocast("cuda", dtype=torch.bfloat16):
            return model(x)

    def bf16_cl() -> object:
        with torch.inference_mode(), torch.autocast("cuda", dtype=torch.bfloat16):
            return cl(xc)

    static_in = xc.clone()
    s = torch.cuda.Stream()
    s.wait_stream(torch.cuda.current_stream())
    with torch.cuda.stream(s), torch.inference_mode(), torch.autocast("cuda", dtype=torch.bfloat16):
        for _ in range(3):
            cl(static_in)
    torch.cuda.current_stream().wait_stream(s)
    graph = torch.cuda.CUDAGraph()
    with torch.cuda.graph(graph), torch.inference_mode(), torch.autocast("cuda", dtype=torch.bfloat16):
        cl(static_in)
    return {"forward bf16": bf16, "forward bf16 channels-last": bf16_cl, "forward bf16 CUDA graph": graph.replay}


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

    ms = timeit(step, steps, torch.cuda.synchronize)
    return batch * 1000 / ms


if __name__ == "__main__":
    main()
