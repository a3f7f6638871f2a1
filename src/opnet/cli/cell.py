"""``opnet-cell``: set a cell up from its own depth frames (no ground truth), and check it against generated piles.

    opnet-cell <frames> --camera <camera file> [--extrinsics <T_base_cam yaml>] [--name N] [--out FILE]
               [--sensor PRESET] [--depth-scale S] [--area=X0,Y0,X1,Y1] [--area-margin M] [--volume-margin M]
               [--figure PNG] [--force]
    opnet-cell check <cell name or file> <frames> --object <o> [--out DIR] [--piles N] [--drops D] [--force]

The first form fits the plane the bin stands on, finds the bin in each frame (inner floor, walls, rim,
where it stands and how it is turned; :mod:`opnet.cell.bin_view`), prints what it found with the spread over
the frames, and writes ``conf/cell/N.yaml`` (the camera's pose over the bin floor, the working volume and
area, the bin, the crop side, the camera file, the sensor preset if given) and a PNG of it drawn on the
first frame beside it. Frames: PNG / NPY / folders of them / a BOP split (its ``cam_K`` and ``depth_scale``
are read, its ground truth never). With ``--extrinsics`` the camera's tilt comes from the calibration (its
base z axis is the floor's normal) and the frames check it. The second form is the sim-versus-real check
(:mod:`opnet.cell.check`). Bad input is one line on stderr naming the file and what is wrong, exit 2,
nothing written.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def _numbers(text: str, count: int, option: str) -> list[float]:
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise ValueError(f"{option} {text}: expected {count} comma-separated numbers") from None
    if len(values) != count or not all(v == v and abs(v) < 1e3 for v in values):
        raise ValueError(f"{option} {text}: expected {count} comma-separated finite numbers (metres)")
    return values


def _positive(value: float, option: str, largest: float) -> float:
    if not (value == value and 0 <= value <= largest):
        raise ValueError(f"{option} {value:g}: expected metres in [0, {largest:g}]")
    return value


def measure_main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="opnet-cell", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("frames", type=Path, help="depth frames: a PNG, a .npy, a folder of them or a BOP split")
    ap.add_argument("--camera", type=Path, required=True, help="the camera file (YAML of fx fy cx cy width height "
                    "clip_start clip_end, a camera_params.txt or a parameter.json); its clip planes bound the depth read")
    ap.add_argument("--extrinsics", type=Path, default=None, help="a YAML with T_base_cam (4 x 4, metres)")
    ap.add_argument("--name", default=None, help="the cell's name (default: --out's stem, else 'cell')")
    ap.add_argument("--out", type=Path, default=None, help="the cell file (default conf/cell/<name>.yaml)")
    ap.add_argument("--sensor", default=None, help="the sensor preset of conf/sensor/ to write (opnet-cell check compares them)")
    ap.add_argument("--depth-scale", type=float, default=None, help="metres per unit of integer frames (0.001: mm)")
    ap.add_argument("--area", default=None, help="the working area, --area=X0,Y0,X1,Y1 (metres, the generator's "
                    "world; the '=' lets it start with a minus)")
    ap.add_argument("--area-margin", type=float, default=0.1, help="the area: where the bin stood plus this (m)")
    ap.add_argument("--volume-margin", type=float, default=0.1, help="the working volume: this far above the rim and "
                    "below the floor (m)")
    ap.add_argument("--figure", type=Path, default=None, help="the PNG of the cell drawn on the first frame "
                    "(default: --out with .png)")
    ap.add_argument("--force", action="store_true", help="replace an existing --out")
    args = ap.parse_args(argv)
    from opnet.cli.tools import tool_main

    return tool_main(lambda: _measure(args))


def _measure(args: argparse.Namespace) -> int:
    from opnet.cell.cellfile import check_cell_name
    from opnet.cli.tools import require_writable
    from opnet.paths import config_dir

    name = check_cell_name(args.name or (args.out.stem if args.out is not None else "cell"), "--name")
    out = args.out or config_dir() / "cell" / f"{name}.yaml"
    png = args.figure or out.with_suffix(".png")
    sensors = sorted(p.stem for p in (config_dir() / "sensor").glob("*.yaml"))
    if args.sensor is not None and args.sensor not in sensors:
        raise ValueError(f"--sensor {args.sensor!r}: expected one of {sensors} (conf/sensor/)")
    area = None if args.area is None else _numbers(args.area, 4, "--area")
    if area is not None and not (area[0] < area[2] and area[1] < area[3]):
        raise ValueError(f"--area {args.area}: expected X0 < X1 and Y0 < Y1")
    area_margin = _positive(args.area_margin, "--area-margin", 5.0)
    volume_margin = _positive(args.volume_margin, "--volume-margin", 2.0)
    for target in (out, png):
        require_writable(target, "--out", replace=args.force)
        if target.resolve() in (args.frames.resolve(), args.camera.resolve()):
            raise ValueError(f"{target}: --out would overwrite an input")
    from opnet.cell.estimate import measure_cell, read_extrinsics
    from opnet.cell.frames import frames_summary, read_frames
    from opnet.datasets.camera_file import read_camera_file

    camera = read_camera_file(args.camera)
    extrinsics = None if args.extrinsics is None else read_extrinsics(args.extrinsics)
    frames = read_frames(args.frames, camera, args.camera, args.depth_scale)
    print(f"{args.frames}: {frames_summary(frames)}; camera {args.camera}")
    cell = measure_cell(frames, camera, extrinsics, str(args.extrinsics), area, area_margin, volume_margin)
    from opnet.cell.cellfile import cell_yaml, summary_lines
    from opnet.cell.figure import draw_cell
    from opnet.fileio.atomic import write_text_atomic

    print("\n".join(summary_lines(cell)))
    out.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out, cell_yaml(cell, name, args.camera, str(args.frames), args.sensor))
    draw_cell(cell, frames[0].depth, cell.views[0], png, f"cell {name}: {frames[0].name}")
    print(f"wrote {_shown(out)} and {_shown(png)}\nnext: python train.py experiment=cell cell={name} object=<your part>"
          + ("" if args.sensor else " sensor=<preset>"))
    return 0


def _shown(path: Path) -> str:
    """``path`` relative to the working folder where it lies below it (the console's lines), else as it is."""
    try:
        return str(path.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["check"]:
        from opnet.cli.cell_check import check_main

        return check_main(argv[1:])
    return measure_main(argv)


if __name__ == "__main__":
    sys.exit(main())
