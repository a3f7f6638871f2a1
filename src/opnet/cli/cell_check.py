"""``opnet-cell check``: a cell's real frames against generated piles of its recipe, before any training
(:mod:`opnet.cell.check`): one table (``README.md``, with the command), its numbers (``check.json``) and one
picture (``check.png``) in ``--out``; the generated piles in ``--work``.

    opnet-cell check <cell> <frames> --object <o> [--out DIR] [--work DIR] [--piles N] [--drops D] [--scale S]
                     [--depth-scale S] [--force]

``<cell>`` is a cell file's name (``conf/cell/<cell>.yaml``, as ``train.py experiment=cell cell=<cell>``
composes it) or a path ``<folder>/cell/<name>.yaml``; the piles are ``--piles`` piles of the recipe's drops at ``--scale`` x the camera's pixels
(``scene.camera_scale``), ideal depth to which each sensor preset of ``conf/sensor/`` is applied, plus one
empty bin rendered at full size where the real one stood. Bad input is one line naming the file or
option, exit 2, nothing written.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
from pathlib import Path
from typing import Any

import numpy as np

OUTPUTS = ("README.md", "check.json", "check.png")


def _compose(cell: str, obj: str) -> Any:
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from opnet.cell.cellfile import check_cell_name
    from opnet.cli.build import absolutize_paths
    from opnet.cli.cell_train import state_cell
    from opnet.paths import config_dir

    path = Path(cell)
    extra = []
    if path.suffix == ".yaml":  # a cell file outside conf/: its folder's parent joins the config search path
        if path.parent.name != "cell" or not path.is_file():
            raise ValueError(f"{path}: not a cell file (<folder>/cell/<name>.yaml, as opnet-cell --out writes it)")
        cell, extra = path.stem, [f"hydra.searchpath=[file://{path.parent.parent.resolve()}]"]
    elif not (config_dir() / "cell" / f"{cell}.yaml").is_file():
        raise ValueError(f"{config_dir() / 'cell' / (cell + '.yaml')}: no such cell file (opnet-cell --name {cell} writes it)")
    check_cell_name(cell, "cell")
    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        cfg = compose(config_name="train", overrides=["experiment=cell", f"cell={cell}", f"object={obj}", *extra])
    OmegaConf.update(cfg, "paths.root_dir", str(Path(cfg.paths.root_dir).resolve()), force_add=True)
    absolutize_paths(cfg)
    state_cell(cfg)
    return cfg


def _presets() -> dict[str, dict[str, Any]]:
    from opnet.datasets.camera_file import read_yaml
    from opnet.paths import config_dir

    return {p.stem: read_yaml(p, "sensor preset") for p in sorted((config_dir() / "sensor").glob("*.yaml"))}


def _generate(cfg: Any, out: Path, cycles: int, drops: int, **scene: Any) -> Any:
    from omegaconf import OmegaConf

    from opnet.datasets.ipa import IPADataset
    from opnet.objects.config import object_from_config
    from opnet.synthesis.config import SceneConfig
    from opnet.synthesis.generate import generate_dataset

    settings = OmegaConf.to_container(cfg.data.generate.scene, resolve=True)
    settings.update(scene)
    obj = object_from_config(OmegaConf.to_container(cfg.object, resolve=True))
    generate_dataset(obj, out, cycles=cycles, drops=drops, workers=1, seed=0, scene=SceneConfig.from_dict(settings),
                     progress=False, previews=0)
    return IPADataset(out)


def check_main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="opnet-cell check", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("cell", help="the cell file's name (conf/cell/<cell>.yaml), or a path <folder>/cell/<name>.yaml")
    ap.add_argument("frames", type=Path, help="the cell's real depth frames (as opnet-cell reads them)")
    ap.add_argument("--object", required=True, help="the part (conf/object/ name or a built-in)")
    ap.add_argument("--out", type=Path, default=None, help="the table and picture (default outputs/cell_check/<cell>)")
    ap.add_argument("--work", type=Path, default=None, help="the generated piles (default <out>/piles)")
    ap.add_argument("--piles", type=int, default=2, help="generated piles")
    ap.add_argument("--drops", type=int, default=None, help="parts dropped per pile (default: the recipe's)")
    ap.add_argument("--scale", type=float, default=0.5, help="the piles at this x the camera's pixels")
    ap.add_argument("--depth-scale", type=float, default=None, help="metres per unit of integer frames")
    ap.add_argument("--force", action="store_true", help="replace the table, numbers and picture in --out")
    args = ap.parse_args(argv)
    from opnet.cli.tools import tool_main

    return tool_main(lambda: _check(args, argv))


def _check(args: argparse.Namespace, argv: list[str]) -> int:
    from opnet.cell.check_report import draw, table
    from opnet.cell.frames import read_frames
    from opnet.cli.tools import require_folder, require_writable
    from opnet.datasets.camera_file import read_camera_file
    from opnet.fileio.atomic import write_text_atomic

    out = args.out or Path("outputs") / "cell_check" / Path(args.cell).stem
    work = args.work or out / "piles"
    if not 1 <= args.piles <= 50:
        raise ValueError(f"--piles {args.piles}: expected 1..50")
    if args.drops is not None and not 0 <= args.drops <= 254:
        raise ValueError(f"--drops {args.drops}: expected 0..254")
    if not 0 < args.scale <= 1:
        raise ValueError(f"--scale {args.scale:g}: expected a number in (0, 1]")
    require_folder(out, "--out")
    for name in OUTPUTS:
        require_writable(out / name, "--out", replace=args.force)
    cfg = _compose(args.cell, args.object)
    camera_file = Path(cfg.scene.camera_file)
    camera = read_camera_file(camera_file)
    frames = read_frames(args.frames, camera, camera_file, args.depth_scale)
    result = run_check(cfg, Path(args.cell).stem, frames, camera, work, args.piles, args.scale, args.drops)
    command = "opnet-cell check " + " ".join(shlex.quote(a) for a in argv)
    text = table(result, command)
    out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out / "README.md", text)
    write_text_atomic(out / "check.json", json.dumps(result["numbers"], indent=1, sort_keys=True) + "\n")
    draw(result, out / "check.png")
    print(text)
    print(f"wrote {out / 'README.md'}, check.json and check.png")
    return 0


def run_check(cfg: Any, cell: str, frames: list[Any], camera: Any, work: Path, piles: int, scale: float,
              drops: int | None = None) -> dict[str, Any]:
    """Measure the real frames, generate the piles and the empty bin, and compare (the numbers and the
    arrays the table and the picture need)."""
    from omegaconf import OmegaConf

    from opnet.cell import check, rig
    from opnet.cell.estimate import measure_cell
    from opnet.synthesis.sensor import SensorModel, sensor_rng
    from opnet.synthesis.working_volume import parse_clip

    value = cfg.scene.clip
    clip = parse_clip(OmegaConf.to_container(value) if OmegaConf.is_config(value) else value, float("inf"))
    if not all(isinstance(plane, float) for plane in clip):
        raise ValueError(f"scene.clip={clip!r}: the check needs the cell's working volume in metres, "
                         "[near, far] (the cell file's)")
    real = [check.frame_stats(f.name, f.depth, camera, clip) for f in frames]
    found = [(f, s) for f, s in zip(frames, real, strict=True) if s.view is not None]
    if not found:
        raise ValueError(f"{frames[0].name}: no bin in any of the {len(frames)} frame(s) ({real[0].error})")
    cell_now = measure_cell([f for f, _ in found], camera, views=[s.view for _, s in found])
    T = rig.world_from_camera(cell_now.floor, camera)
    drops = int(cfg.data.generate.drops) if drops is None else drops
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    ideal = _generate(cfg, work / f"piles_c{piles}_d{drops}_x{scale:g}", piles, drops, camera_scale=scale, views=1)
    presets = {name: SensorModel.from_dict(values).scaled(scale) for name, values in _presets().items()}
    recipe = str(cfg.sensor.name)
    generated: dict[str, list[Any]] = {}
    first_depth = {}
    for name, sensor in presets.items():
        stats = []
        for i in range(len(ideal)):
            record = ideal[i]
            cycle, scene = (int(v) for v in record.name.replace("cycle_", "").split("_"))
            depth = check.sensor_depth(sensor, record.depth, record.camera, clip, sensor_rng(0, cycle, scene))
            stats.append(check.frame_stats(record.name, depth, record.camera, clip, record.segmentation))
            if i == len(ideal) - 1:
                first_depth[name] = (depth, record.camera)
        generated[name] = stats
    # the empty bin where the first real bin stood, full size, no jitter: its floor against the real one's
    frame, stats0 = found[0]
    x, y, yaw = rig.bin_placement(T, stats0.view.centre, stats0.view.axis)
    empty = _generate(cfg, work / "empty_bin", 1, 0, camera_scale=1.0, views=1, bin_area=[x, y, x, y],
                      bin_yaw_deg=[yaw, yaw], camera_jitter_m=0.0, camera_jitter_deg=0.0, clutter=0)
    residual = check.floor_residual(frame.depth, stats0.view, empty[0].depth, camera)
    numbers = _numbers(real, generated, recipe, residual, T, clip, cell_now)
    numbers["cell"] = cell
    numbers["piles"] = {"count": piles, "drops": drops, "scale": scale, "scenes": len(ideal)}
    return {"numbers": numbers, "real": real, "generated": generated[recipe], "recipe": recipe,
            "real_depth": frame.depth, "real_view": stats0.view, "camera": camera,
            "generated_depth": first_depth[recipe], "residual": residual, "clip": clip,
            "presets": {k: check.summary(v) for k, v in generated.items()}}


def _numbers(real: list[Any], generated: dict[str, list[Any]], recipe: str, residual: np.ndarray, T: np.ndarray,
             clip: tuple[float, float], cell_now: Any) -> dict[str, Any]:  # fmt: skip
    from opnet.cell import check

    gen = generated[recipe]
    h_real, h_gen = check.histogram([s.depths for s in real], clip), check.histogram([s.depths for s in gen], clip)

    def side(stats: list[Any]) -> dict[str, Any]:
        depths = np.concatenate([s.depths for s in stats]) if stats else np.zeros(0)
        views = [s.view for s in stats if s.view is not None]
        place = check.placements(stats, T)
        return {"frames": len(stats), "found": len(views),
                "in_volume": check.mean_of([s.in_volume for s in stats]),
                "depth_p5_p50_p95": [float(v) for v in np.percentile(depths, [5, 50, 95])] if depths.size else None,
                "missing_in_bin": check.mean_of([s.missing_in_bin for s in stats]),
                "missing_off_bin": check.mean_of([s.missing_off_bin for s in stats]),
                "missing_on_parts": check.mean_of([s.missing_on_parts for s in stats]),
                "missing_off_parts": check.mean_of([s.missing_off_parts for s in stats]),
                "inner": [check.median_of([v.sides[k] for v in views]) for k in (0, 1)],
                "wall_height": check.median_of([v.wall_height for v in views]),
                "floor_rms": check.median_of([v.floor_rms for v in views]),
                "camera_tilt_azimuth_height": [check.median_of([s.pose[k] for s in stats if s.pose]) for k in range(3)],
                "x_range": [float(place[:, 0].min()), float(place[:, 0].max())] if len(place) else None,
                "y_range": [float(place[:, 1].min()), float(place[:, 1].max())] if len(place) else None,
                "errors": [s.error for s in stats if s.error][:3]}

    real_summary = check.summary(real)
    presets = {name: {**check.summary(stats), "distance": check.preset_distance(real_summary, check.summary(stats))}
               for name, stats in generated.items()}
    r = residual[np.isfinite(residual)]
    return {"real": side(real), "generated": side(gen), "recipe_sensor": recipe, "histogram_overlap": check.overlap(h_real, h_gen),
            "floor_residual_mm": {"pixels": int(r.size), "median": float(np.median(r) * 1000) if r.size else None,
                                  "p90_abs": float(np.percentile(np.abs(r), 90) * 1000) if r.size else None},
            "presets": presets, "closest_preset": min(presets, key=lambda k: presets[k]["distance"]),
            "working_volume": list(clip), "camera_now": {"tilt_deg": cell_now.tilt_deg, "azimuth_deg": cell_now.azimuth_deg,
                                                         "height": cell_now.camera_height}}


if __name__ == "__main__":
    sys.exit(check_main(sys.argv[1:]))
