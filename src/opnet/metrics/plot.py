"""Precision-recall plot of an evaluation (matplotlib, off-screen Agg canvas, no pyplot state)."""

from __future__ import annotations

import io
from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from opnet.fileio.atomic import write_bytes_atomic
from opnet.metrics.report import EvaluationSummary


def pr_curve_figure(precision, recall, title: str = "") -> Figure:  # noqa: ANN001 - 1-D arrays
    """The scene-averaged PR curve as a matplotlib Figure (no pyplot state; TensorBoard takes it).

    A step plot: precision p_k over recall (r_{k-1}, r_k], the way AP integrates it.
    """
    fig = Figure(figsize=(5.5, 4.5), dpi=120)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    ax.step(recall, precision, where="pre", color="C0", lw=1.5, label="mean over scenes")
    ax.set(xlim=(0, 1.02), ylim=(0, 1.02), xlabel="recall", ylabel="precision")
    ax.grid(alpha=0.3)
    if title:
        ax.set_title(title, fontsize=9)
    ax.legend(loc="lower left", fontsize=8)
    fig.tight_layout()
    return fig


def plot_pr_curve(summary: EvaluationSummary, path: str | Path, title: str = "") -> None:
    """Save the scene-averaged PR curve to an image file.

    Args:
        summary: result of :func:`opnet.metrics.evaluate_scenes`.
        path: destination; the format follows the suffix (.png, .pdf, .svg). Written atomically.
        title: optional first line of the title (the metrics follow).
    """
    path = Path(path)
    metrics = f"AP {summary.ap:.4f}  MAP {summary.map:.4f}  F1 {summary.f1:.4f}"
    metrics += f"  ({summary.num_scenes} scenes)"
    fig = pr_curve_figure(summary.precision, summary.recall, f"{title}\n{metrics}" if title else metrics)
    buffer = io.BytesIO()
    fig.savefig(buffer, format=path.suffix.lstrip(".").lower() or "png")
    write_bytes_atomic(path, buffer.getvalue())
