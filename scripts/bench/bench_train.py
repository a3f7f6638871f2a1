"""Training throughput of the real pipeline (data -> encode -> forward -> loss -> backward -> step),
for the speed options of the CPU: memory format, mixed precision, DataLoader workers, scene cache.

    python scripts/bench/bench_train.py --data <IPA dataset> [--steps 60] [--warmup 15]
    python scripts/bench/bench_train.py --data <dir> --arms fp32 bf16+cl --workers 0 1
    python scripts/bench/bench_train.py --data <dir> --accelerator gpu --arms bf16+cl --workers 8 --network-alone \
        --extra experiment=paper data.generate=null --throughput-out results/gpu/train_throughput.csv

Each arm runs ``train.py``'s own components (Hydra config ``train`` with the arm's overrides) in a
Lightning ``Trainer`` for ``warmup + steps`` optimizer steps and times the last ``steps`` (a
callback reads the clock at every batch end); validation and checkpoints are off. Prints images/s
per arm and the speed-up over the first arm. Run it on a quiet machine: another busy process on
the two cores halves every figure.

``--network-alone``: beside each arm, the network by itself at the arm's batch size, precision and
memory format (random input on the device, forward, loss, backward, optimizer step:
:func:`opnet.models.stats.train_images_per_s`), i.e. what the loop would reach if data, encoding
and the loss cost nothing; ``--throughput-out`` writes both per arm (device, network, batch,
precision, arm, workers, cache, loop_images_per_s, network_images_per_s).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import torch  # noqa: E402

from opnet.fileio.atomic import append_csv_rows
from opnet.studies.training import measure

ARMS: dict[str, list[str]] = {
    "fp32": ["trainer.precision=32", "model.channels_last=false"],
    "cl": ["trainer.precision=32", "model.channels_last=true"],
    "bf16": ["trainer.precision=bf16-mixed", "model.channels_last=false"],
    "bf16+cl": ["trainer.precision=bf16-mixed", "model.channels_last=true"],
}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, required=True, help="an IPA-layout dataset folder")
    parser.add_argument("--object", default=None, help="object config name (default: from the dataset)")
    parser.add_argument("--arms", nargs="+", default=list(ARMS), choices=list(ARMS))
    parser.add_argument("--workers", nargs="+", type=int, default=[0])
    parser.add_argument("--cache", nargs="+", default=["true"], choices=["true", "false"])
    parser.add_argument("--steps", type=int, default=60)
    parser.add_argument("--warmup", type=int, default=15)
    parser.add_argument("--extra", nargs="*", default=[], help="further Hydra overrides for every arm")
    parser.add_argument("--out", type=Path, help="append the rows to this CSV (e.g. results/speed/train.csv)")
    parser.add_argument("--accelerator", default="cpu", choices=["cpu", "gpu"])
    parser.add_argument("--network-alone", action="store_true",
                        help="also time the network alone at each arm's batch size and precision")
    parser.add_argument("--throughput-out", type=Path, help="write loop and network-alone images/s to this CSV (replaced)")
    args = parser.parse_args(argv)
    import json

    obj = args.object or json.loads((args.data / "object.json").read_text())["name"]
    base = [f"object={obj}", "data=ipa", f"data.root={args.data.resolve()}", *args.extra]
    rows, details = [], []
    for cache in args.cache:
        for workers in args.workers:
            for arm in args.arms:
                overrides = [*base, *ARMS[arm], f"data.num_workers={workers}", f"data.cache={cache}"]
                ips, alone, what = measure(overrides, args.steps, args.warmup, args.accelerator, args.network_alone)
                rows.append((arm, workers, cache, ips))
                details.append((alone, what))
                network = f", the network alone {alone:6.1f}" if alone is not None else ""
                print(f"  {arm:8s} workers={workers} cache={cache}: {ips:6.1f} images/s{network}", flush=True)
    ref = rows[0][3]
    print(f"\ntorch {torch.__version__}, {torch.get_num_threads()} threads, batch from the config, "
          f"{args.steps} timed steps after {args.warmup}")  # fmt: skip
    print("| arm | DataLoader workers | scene cache | train images/s | speed-up |")
    print("|---|---|---|---|---|")
    for arm, workers, cache, ips in rows:
        print(f"| {arm} | {workers} | {cache} | {ips:.1f} | {ips / ref:.2f}x |")
    if args.out is not None:
        append_csv_rows(args.out, ["arm", "workers", "cache", "images_per_s"],
                    [[arm, workers, cache, f"{ips:.1f}"] for arm, workers, cache, ips in rows])
    if args.throughput_out is not None:
        device = torch.cuda.get_device_name() if args.accelerator == "gpu" else "cpu"
        lines = ["device,network,batch,precision,arm,workers,cache,loop_images_per_s,network_images_per_s"]
        lines += [f"{device},{w['network']},{w['batch']},{w['precision']},{arm},{workers},{cache},{ips:.1f},"
                  f"{'' if alone is None else f'{alone:.1f}'}" for (arm, workers, cache, ips), (alone, w) in zip(rows, details)]
        args.throughput_out.parent.mkdir(parents=True, exist_ok=True)
        args.throughput_out.write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
