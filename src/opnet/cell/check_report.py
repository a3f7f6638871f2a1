"""The sim-versus-real check's table (markdown) and picture (:mod:`opnet.cell.check`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from opnet.cell import check


def _pct(v: float | None) -> str:
    return "–" if v is None or not np.isfinite(v) else f"{100 * v:.1f} %"


def _m(values: list[float] | None, digits: int = 3) -> str:
    if values is None or not all(v is not None and np.isfinite(v) for v in values):
        return "–"
    return " / ".join(f"{v:.{digits}f}" for v in values)


def _range(values: list[float] | None) -> str:
    return "–" if values is None else (f"{values[0]:.3f}" if values[0] == values[1] else f"{values[0]:.3f}..{values[1]:.3f}")


def table(result: dict[str, Any], command: str) -> str:
    """The check's page: the command, the table of real against generated, the presets, the notes."""
    n = result["numbers"]
    r, g = n["real"], n["generated"]
    piles = n["piles"]
    res = n["floor_residual_mm"]
    rows = [("frames", str(r["frames"]), f"{g['frames']} ({piles['count']} piles x {piles['drops'] + 1} scenes, "
             f"{piles['scale']:g} x the pixels)"),
            ("valid depth in the working volume", _pct(r["in_volume"]), _pct(g["in_volume"])),
            ("depth in the working volume: 5th / 50th / 95th percentile (m)", _m(r["depth_p5_p50_p95"]),
             _m(g["depth_p5_p50_p95"])),
            ("overlap of the two depth histograms (1 cm bins)", "", f"{n['histogram_overlap']:.2f}"),
            ("missing depth in the bin (inner outline, floor to rim)", _pct(r["missing_in_bin"]), _pct(g["missing_in_bin"])),
            ("missing depth off the bin", _pct(r["missing_off_bin"]), _pct(g["missing_off_bin"])),
            ("missing depth on the parts / off them", "– (no masks without ground truth)",
             f"{_pct(g['missing_on_parts'])} / {_pct(g['missing_off_parts'])}"),
            ("bin found", f"{r['found']} of {r['frames']}", f"{g['found']} of {g['frames']}"),
            ("bin inner (m)", _m(r["inner"]), _m(g["inner"])),
            ("bin wall height (m)", _m([r["wall_height"]]), _m([g["wall_height"]])),
            ("camera tilt (deg) / azimuth (deg) / height (m) over the found floor",
             _m(r["camera_tilt_azimuth_height"], 3), _m(g["camera_tilt_azimuth_height"], 3)),
            ("bin centre x, y (m, the generator's world)", f"{_range(r['x_range'])}, {_range(r['y_range'])}",
             f"{_range(g['x_range'])}, {_range(g['y_range'])}"),
            ("floor noise: rms over the floor's inliers (mm)", f"{1000 * r['floor_rms']:.2f}",
             f"{1000 * g['floor_rms']:.2f}"),
            ("floor depth, real minus an empty generated bin where the real one stood: median, 90th pct of |.| (mm)",
             "", "–" if res["median"] is None else f"{res['median']:+.1f}, {res['p90_abs']:.1f} ({res['pixels']} px)")]
    lines = [f"# Sim versus real: cell `{n['cell']}`", "", f"Made by `{command}` (no ground truth read).", "",
             f"| | real frames | generated piles (sensor={n['recipe_sensor']}) |", "|---|---|---|",
             *(f"| {a} | {b} | {c} |" for a, b, c in rows), "",
             "Sensor presets applied to the same generated piles' ideal depth, against the real frames "
             "(distance: the missing shares' differences in percentage points plus the floor noise's in mm):", "",
             "| depth | missing in the bin | missing off the bin | floor noise (mm) | distance |", "|---|---|---|---|---|",
             f"| real frames | {_pct(r['missing_in_bin'])} | {_pct(r['missing_off_bin'])} | {1000 * r['floor_rms']:.2f} | |"]
    for name, p in sorted(n["presets"].items(), key=lambda kv: kv[1]["distance"]):
        mark = " (closest)" if name == n["closest_preset"] else ""
        lines.append(f"| sensor={name}{mark} | {_pct(p['missing_in_bin'])} | {_pct(p['missing_off_bin'])} | "
                     f"{1000 * p['floor_rms']:.2f} | {p['distance']:.1f} |")
    errors = r["errors"] + g["errors"]
    if errors:
        lines += ["", "Frames without a bin: " + "; ".join(errors)]
    lines += ["", "![real and generated frames, depth histograms, floor residual](check.png)"]
    return "\n".join(lines) + "\n"


def draw(result: dict[str, Any], out: Path) -> None:
    """The picture: the real frame and a generated one with the bins found, the depth histograms, the floor
    residual map."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from opnet.fileio.atomic import write_bytes_atomic

    clip = result["clip"]
    fig, axes = plt.subplots(2, 2, figsize=(13, 9.5))
    gen_depth, gen_camera = result["generated_depth"]
    gen_stats = result["generated"][-1]
    for ax, depth, camera, view, title in ((axes[0, 0], result["real_depth"], result["camera"], result["real_view"],
                                             "real frame"),
                                            (axes[0, 1], gen_depth, gen_camera, gen_stats.view,
                                             f"generated pile (sensor={result['recipe']})")):
        ax.imshow(np.clip(depth, *clip), cmap="viridis_r", vmin=clip[0], vmax=clip[1])
        if view is not None:
            for height, colour in ((0.0, "lime"), (view.wall_height, "orange")):
                c = view.corners(height)
                u = camera.fx * c[:, 0] / c[:, 2] + camera.cx
                v = camera.fy * c[:, 1] / c[:, 2] + camera.cy
                ax.plot(np.r_[u, u[:1]], np.r_[v, v[:1]], color=colour, lw=1.5)
        ax.set_title(f"{title}: bin inner outline at the floor (green) and rim (orange)", fontsize=9)
        ax.axis("off")
    edges = np.arange(clip[0], clip[1] + check.HIST_BIN_M, check.HIST_BIN_M)
    centres = (edges[:-1] + edges[1:]) / 2
    for stats, label in ((result["real"], "real frames"), (result["generated"], f"generated (sensor={result['recipe']})")):
        axes[1, 0].plot(centres, check.histogram([s.depths for s in stats], clip), label=label)
    axes[1, 0].set_xlabel("depth (m), the working volume")
    axes[1, 0].set_ylabel("share of the depth in the working volume")
    axes[1, 0].legend()
    residual = result["residual"] * 1000
    finite = residual[np.isfinite(residual)]
    lim = float(np.percentile(np.abs(finite), 98)) if finite.size else 1.0
    im = axes[1, 1].imshow(residual, cmap="coolwarm", vmin=-lim, vmax=lim)
    rows, cols = np.nonzero(np.isfinite(residual))
    if rows.size:
        axes[1, 1].set_xlim(cols.min() - 20, cols.max() + 20)
        axes[1, 1].set_ylim(rows.max() + 20, rows.min() - 20)
    fig.colorbar(im, ax=axes[1, 1], label="real minus generated empty bin (mm)")
    axes[1, 1].set_title("floor depth residual on the real floor", fontsize=9)
    axes[1, 1].axis("off")
    fig.tight_layout()
    import io

    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=80)
    plt.close(fig)
    write_bytes_atomic(out, buffer.getvalue())
