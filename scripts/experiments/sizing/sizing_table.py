"""The recipes sized to the part: bin, drops, camera, clip planes and the piles they make, from a
15 mm pin to a 450 mm shaft (results/sizing/README.md).

    python scripts/experiments/sizing/sizing_table.py --generate            # make the piles (outputs/sizing/), then the table
    python scripts/experiments/sizing/sizing_table.py --out results/sizing  # the table of what is there

Each part is generated with a recipe's own generator settings, as ``train.py experiment=<recipe>``
would (conf/experiment/quickstart.yaml: scene=train, 10 drops; conf/experiment/dense.yaml: the bulk
scene, 75 drops, the Siléane bunny camera 1.5 m above the floor with its clip planes and jitters for
the bunny, scaled to the part by D / the bunny's D, ``scene.rig_d``; 8 views per pile), only fewer
cycles and one worker. ``dense_fixed`` is the dense recipe as it was before it sized its rig (1.5 m
for every part); ``dense_sized`` the dense recipe with the camera height and clip planes derived
from the bin (``scene.camera_height=null scene.clip=null``: the same intrinsics). Parts other than the configured ones are built-in meshes written to STL and
scaled (``object.mesh_scale``) so that D, as opnet measures it (the object's diameter), is the
size named. Per dataset: D, the bin (inner side, wall height), drops, camera height, clip planes,
D in pixels on the floor (written image; at the 128-pixel network input), seconds per pile
(generation log: wall time after start-up over piles simulated), start-up seconds (imports, the
convex decomposition on a cache miss), re-drops and unsettled drops, and scripts/bench/pile_stats.py's
pile statistics.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import re
import sys
from pathlib import Path

from omegaconf import OmegaConf

from opnet.objects import builtin_object, object_from_config
from opnet.paths import REPO_ROOT
from opnet.studies import run_logged
from opnet.studies.scenes import VIS_LABELS, pile_stats
from opnet.synthesis import SceneConfig
from opnet.synthesis.layout import make_rig

INPUT_SIZE = 128  # conf/data/*.yaml input_size
MESHES = "meshes"  # built-in meshes written as STL, under the work folder

#: part -> (built-in mesh written to STL or None, target D in mm or None, object overrides)
PARTS: dict[str, tuple[str | None, float | None, list[str]]] = {
    "pin15": ("pin", 15.0, ["++object.symmetry.rotoreflection=true"]),
    "pin": (None, None, ["object=pin"]),
    "shaft": (None, None, ["object=shaft"]),
    "ring_screw": (None, None, ["object=ring_screw"]),
    "bunny": (None, None, ["object=bunny"]),
    "shaft450": ("shaft", 450.0, []),
}

DENSE = ["scene=bulk", "scene.camera_file=conf/cameras/sileane_bunny.yaml", "scene.clip=camera",
         "scene.camera_height=1.5", "scene.views=8", "scene.camera_jitter_m=0.03", "scene.camera_jitter_deg=3.0",
         "scene.bin_jitter_m=0.03", "scene.bin_jitter_deg=15.0", "drops=75"]
#: the part diameter experiment=dense sizes its rig for (the bunny's)
DENSE_RIG_D = OmegaConf.load(REPO_ROOT / "conf" / "experiment" / "dense.yaml").scene.rig_d
#: recipe -> (generate.py overrides, cycles)
RECIPES: dict[str, tuple[list[str], int]] = {
    "quickstart": (["scene=train", "drops=10"], 3),
    "dense": ([*DENSE, f"scene.rig_d={DENSE_RIG_D}"], 8),
    "dense_fixed": (DENSE, 8),
    "dense_sized": ([*DENSE, "scene.camera_height=null", "scene.clip=null"], 8),
}
#: the scene's absolute lengths (wall thickness 10 mm, jitters 5-30 mm, drop gap 10 mm) cut by hand to a
#: small part's size, as measured before the generator scaled them itself (scene.small_part_d; 0 here: these
#: values as given): the recipes above, measured on the 15 mm pin with these as well
SMALL = ["scene.bin_wall_thickness=0.002", "scene.drop_gap=0.002", "scene.small_part_d=0"]
RECIPES |= {
    "quickstart_small": ([*RECIPES["quickstart"][0], *SMALL, "scene.bin_jitter_m=0.002", "scene.camera_jitter_m=0.001"], 3),
    "dense_sized_small": ([*RECIPES["dense_sized"][0], *SMALL, "scene.bin_jitter_m=0.005", "scene.camera_jitter_m=0.005"], 8),
}

LOG_LINE = re.compile(r"(\d+) scenes in ([\d.]+) s \(([\d.]+) scenes/s after ([\d.]+) s start-up\); "
                      r"re-drops (\d+), unsettled drops (\d+)")


def object_overrides(part: str, work: Path) -> list[str]:
    builtin, size_mm, extra = PARTS[part]
    if builtin is None:
        return extra
    mesh = work / MESHES / f"{builtin}.stl"
    obj = builtin_object(builtin)
    if not mesh.exists():
        mesh.parent.mkdir(parents=True, exist_ok=True)
        obj.mesh.export(mesh)
    symmetry = obj.symmetry
    return ["object=gear_shaft", f"object.name={part}", f"object.mesh={mesh}",
            f"object.mesh_scale={size_mm / 1e3 / obj.diameter:.6g}", f"object.symmetry.kind={symmetry.kind}", *extra]


def generate_command(part: str, recipe: str, work: Path) -> list[str]:
    overrides, cycles = RECIPES[recipe]
    return ["generate.py", *object_overrides(part, work), *overrides, f"cycles={cycles}", "seed=0", "workers=1",
            "previews=1", "progress=false", f"out={work / f'{part}_{recipe}'}"]


def row(root: Path) -> dict:
    """The sizing row of one generated folder (module docstring)."""
    gen = json.loads((root / "generation.json").read_text())
    obj = object_from_config(gen["object"])
    scene = SceneConfig.from_dict(gen["scene"])
    cycles = json.loads((root / "parameter.json").read_text())["number_cycles"]
    rig = make_rig(obj, gen["drops"], cycles, scene)
    h = float(rig.params.location[2])
    cam = rig.camera
    d_px = obj.diameter * cam.fx / h
    out = {"dataset": root.name, "D_mm": 1e3 * obj.diameter, "bin_inner_mm": 1e3 * rig.bin.inner,
           "wall_mm": 1e3 * rig.bin.wall_height, "drops": gen["drops"], "camera_height_mm": 1e3 * h,
           "clip_start_mm": 1e3 * cam.clip_start, "clip_end_mm": 1e3 * cam.clip_end,
           "image": f"{cam.width}x{cam.height}", "D_px": d_px, "D_px_128": d_px * INPUT_SIZE / max(cam.width, cam.height)}
    log = root.parent / f"{root.name}.log"
    m = LOG_LINE.search(log.read_text()) if log.exists() else None
    if m:
        _, secs, _, startup, redrops, unsettled = m.groups()
        piles = cycles / max(scene.views, 1)
        out |= {"s_per_pile": (float(secs) - float(startup)) / piles, "startup_s": float(startup),
                "redrops": int(redrops), "unsettled": int(unsettled)}
    stats = pile_stats(root)
    out |= {k: v for k, v in stats.items() if k != "vis_hist"}
    out |= {f"vis {label}": h for label, h in zip(VIS_LABELS, stats["vis_hist"], strict=True)}
    return out


def markdown(rows: list[dict]) -> str:
    head = ["dataset", "D mm", "bin inner x wall mm", "drops", "camera mm", "clip mm", "D px (at 128)", "s / pile",
            "start-up s", "re-drops / unsettled", "parts / scene", *(f"vis {v}" for v in VIS_LABELS),
            "pile top mm (sd)", "mean part height mm", "flat", "hidden (full piles)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        na = "s_per_pile" not in r
        cells = [r["dataset"], f"{r['D_mm']:.0f}", f"{r['bin_inner_mm']:.0f} x {r['wall_mm']:.0f}", str(r["drops"]),
                 f"{r['camera_height_mm']:.0f}", f"{r['clip_start_mm']:.0f}-{r['clip_end_mm']:.0f}",
                 f"{r['D_px']:.0f} ({r['D_px_128']:.1f})", "n/a" if na else f"{r['s_per_pile']:.1f}",
                 "n/a" if na else f"{r['startup_s']:.1f}", "n/a" if na else f"{r['redrops']} / {r['unsettled']}",
                 f"{r['parts_per_scene']:.1f}", *(f"{100 * r[f'vis {v}']:.0f} %" for v in VIS_LABELS),
                 f"{r['height_max_mm']:.0f} ({r['height_max_sd_mm']:.0f})", f"{r['height_mean_mm']:.0f}",
                 f"{100 * r['flat']:.0f} %", f"{100 * r['hidden']:.0f} %"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", type=Path, default=REPO_ROOT / "outputs" / "sizing")
    ap.add_argument("--generate", action="store_true", help="generate the missing datasets first")
    ap.add_argument("--parts", nargs="+", default=list(PARTS), choices=list(PARTS))
    ap.add_argument("--recipes", nargs="+", default=["quickstart", "dense", "dense_fixed", "dense_sized"], choices=list(RECIPES))
    ap.add_argument("--out", type=Path, default=None, help="write sizing.csv and sizing.md here")
    args = ap.parse_args()
    work = args.work.resolve()
    env = {**os.environ, "PYOPENGL_PLATFORM": "egl"}
    rows = []
    for part in args.parts:
        for recipe in args.recipes:
            root, log = work / f"{part}_{recipe}", work / f"{part}_{recipe}.log"
            if args.generate and not LOG_LINE.search(log.read_text() if log.exists() else ""):
                cmd = generate_command(part, recipe, work)
                run_logged([sys.executable, *cmd], log, env=env)
            if (root / "generation.json").exists():
                rows.append(row(root))
                print(markdown(rows[-1:]).splitlines()[-1], flush=True)
    text = markdown(rows)
    print(text)
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "sizing.md").write_text(text + "\n")
        with open(args.out / "sizing.csv", "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]), lineterminator="\n")
            w.writeheader()
            w.writerows({k: f"{v:.4g}" if isinstance(v, float) else v for k, v in r.items()} for r in rows)


if __name__ == "__main__":
    main()
