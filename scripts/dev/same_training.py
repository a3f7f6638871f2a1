"""Whether a change leaves the recipes' training as it was: a short run of each recipe at another commit and
at the working tree, the same seed, their data and their weights compared.

    python scripts/dev/same_training.py --ref <commit> [--recipes quickstart dense_bunny] [--work <dir>]

Each recipe generates a few piles and trains a few steps in both checkouts (the other commit as a git worktree,
``../shared`` linked beside it), each into its own folder. A table: the depth images and ground truth written
(files whose bytes differ; the generator's own records, generation.json and the cache's fingerprint, name their
new keys and are left out), and the largest difference of any weight of the last checkpoint. Bytes and weights
equal: the recipe trains as before, so every figure it made stands. Prints the table; exit 1 where a recipe
differs, 2 on bad input.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import subprocess
import sys
from pathlib import Path

from opnet.paths import REPO_ROOT, shared_dir

#: a few piles and steps of each recipe: enough to run every stage of its generation and training
RECIPES = {
    "quickstart": ["experiment=quickstart", "data.generate.cycles=6", "trainer.max_epochs=2"],
    "dense_bunny": ["experiment=dense", "object=bunny", "data.generate.cycles=4", "scene.views=2",
                    "data.generate.drops=12", "trainer.max_steps=12", "trainer.max_epochs=100"],
}  # fmt: skip
COMMON = ["data.generate.workers=1", "test=false", "trainer.enable_progress_bar=false", "seed=0"]
#: what the generator records of its own settings (new keys appear there), not what a network is shown
RECORDS = ("generation.json", "cache.json")


def checkout(ref: str, work: Path) -> Path:
    """The commit ``ref`` as a worktree under ``work`` (``../shared`` linked beside it)."""
    tree = work / "tree"
    if not tree.is_dir():
        subprocess.run(["git", "worktree", "add", "--detach", "-f", str(tree), ref], cwd=REPO_ROOT, check=True,
                       capture_output=True)  # fmt: skip
    shared = work / "shared"
    if not shared.exists() and shared_dir().is_dir():
        shared.symlink_to(shared_dir().resolve())
    return tree


def train(tree: Path, recipe: str, out: Path) -> Path:
    """The recipe's short run in checkout ``tree`` (its own ``src`` first on the path) into ``out``."""
    env = {**os.environ, "PYOPENGL_PLATFORM": "egl", "PYTHONPATH": str(tree / "src")}
    log = out / "console.log"
    out.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "train.py", *RECIPES[recipe], *COMMON, f"hydra.run.dir={out / 'run'}",
           f"paths.data_dir={out / 'data'}"]  # fmt: skip
    with log.open("w") as f:
        if subprocess.run(cmd, cwd=tree, env=env, stdout=f, stderr=subprocess.STDOUT).returncode:
            raise SystemExit(f"error: {recipe} failed in {tree} (see {log})")
    return out


def digests(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file() and p.name not in RECORDS}  # fmt: skip


def weight_difference(a: Path, b: Path) -> float:
    import torch

    sa = torch.load(a, map_location="cpu", weights_only=False)["state_dict"]
    sb = torch.load(b, map_location="cpu", weights_only=False)["state_dict"]
    if set(sa) != set(sb):
        return float("inf")
    return max(((sa[k].double() - sb[k].double()).abs().max().item() for k in sa), default=0.0)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ref", required=True, help="the commit to compare with")
    ap.add_argument("--recipes", nargs="+", choices=list(RECIPES), default=list(RECIPES))
    ap.add_argument("--work", type=Path, default=REPO_ROOT / "outputs" / "same_training")
    args = ap.parse_args(argv)
    ok = subprocess.run(["git", "rev-parse", "--verify", f"{args.ref}^{{commit}}"], cwd=REPO_ROOT,
                        capture_output=True, text=True)  # fmt: skip
    if ok.returncode:
        print(f"error: --ref {args.ref}: not a commit of {REPO_ROOT}", file=sys.stderr)
        return 2
    ref = ok.stdout.strip()
    work = args.work / ref[:12]
    tree = checkout(ref, work)
    lines = [f"| recipe | files written | differ ({ref[:7]} vs working tree) | largest weight difference |",
             "|---|---|---|---|"]
    same = True
    for recipe in args.recipes:
        old = train(tree, recipe, work / f"{recipe}_ref")
        new = train(REPO_ROOT, recipe, work / f"{recipe}_now")
        a, b = digests(old / "data"), digests(new / "data")
        differ = sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))
        diff = weight_difference(old / "run" / "checkpoints" / "last.ckpt", new / "run" / "checkpoints" / "last.ckpt")
        same &= not differ and diff == 0.0
        lines.append(f"| {recipe} | {len(b)} | {len(differ)}{' (' + ', '.join(differ[:3]) + ')' if differ else ''} "
                     f"| {diff:.3g} |")  # fmt: skip
    print("\n".join(lines))
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
