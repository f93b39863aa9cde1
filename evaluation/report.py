"""Evaluation reports: ``report.json``, a markdown table, and PNG figures (PR curves, max F1 against radius).

Figures are drawn on Matplotlib's Agg canvas directly (no pyplot), so importing
this module never changes the backend of a program that also shows windows.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any, Iterable, Literal, Sequence

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from lostx.core.errors import InputError
from .metrics import Evaluation, PRCurve, max_f1_by_tolerance

Mode = Literal["single", "sequence"]
MODES = ("single", "sequence")
REQUIRED_KEYS = (
    "method", "mode", "tolerance", "tolerance_unit", "recall_at_100p", "max_f1", "auc_pr",
    "recall_at_1", "recall_at_5", "recall_at_10", "n_queries",
)
UNIT_LABELS = {"m": "localization radius (m)", "frames": "frame tolerance (frames)"}


def report_entry(method: str, mode: Mode, evaluation: Evaluation, **extra: Any) -> dict[str, Any]:
    """One row of ``report.json``: the method, its mode and every scalar of the evaluation (plus ``extra``)."""
    if mode not in MODES:
        raise InputError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
    entry: dict[str, Any] = {"method": method, "mode": mode}
    entry.update(evaluation.summary())
    for n in (1, 5, 10):
        entry.setdefault(f"recall_at_{n}", float("nan"))
    entry.update(extra)
    return entry


def _json_ready(value: Any) -> Any:
    # JSON has no NaN: an undefined number (e.g. recall with no matchable query) is written as null.
    if isinstance(value, dict):
        return {k: _json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_ready(v) for v in value]
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return None if not math.isfinite(float(value)) else float(value)
    return value


def write_report_json(path: str | Path, entries: Sequence[dict[str, Any]]) -> Path:
    """Write the entries as a JSON list (atomically); NaN becomes null. Every entry needs ``REQUIRED_KEYS``."""
    for i, entry in enumerate(entries):
        missing = [k for k in REQUIRED_KEYS if k not in entry]
        if missing:
            raise InputError(f"report entry {i} ({entry.get('method', '?')}) lacks {', '.join(missing)}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".partial")
    tmp.write_text(json.dumps(_json_ready(list(entries)), indent=2, allow_nan=False) + "\n")
    os.replace(tmp, path)
    return path


def read_report_json(path: str | Path) -> list[dict[str, Any]]:
    """The entries of a ``report.json`` (null numbers come back as NaN)."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(f"report not found: {path}") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}:{exc.lineno}: not valid JSON ({exc.msg})") from None
    if not isinstance(data, list):
        raise InputError(f"{path}: expected a JSON list of entries")
    return [{k: (float("nan") if v is None else v) for k, v in entry.items()} for entry in data]


def _fmt(value: Any, percent: bool) -> str:
    if isinstance(value, (float, np.floating)):
        if not math.isfinite(float(value)):
            return "n/a"
        return f"{100 * value:.1f}" if percent else f"{value:g}"
    return str(value)


def markdown_table(entries: Iterable[dict[str, Any]]) -> str:
    """A GitHub markdown table of the entries; rates in percent, 'n/a' where undefined."""
    rows = list(entries)
    header = ["method", "mode", "tolerance", "R@100P %", "max F1 %", "AUC-PR %", "R@1 %", "R@5 %", "R@10 %", "queries"]
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(["---"] * 2 + ["---:"] * (len(header) - 2)) + "|"]
    for e in rows:
        cells = [
            str(e["method"]),
            str(e["mode"]),
            f"{_fmt(e['tolerance'], False)} {e['tolerance_unit']}",
            *(_fmt(e[k], True) for k in ("recall_at_100p", "max_f1", "auc_pr", "recall_at_1", "recall_at_5",
                                           "recall_at_10")),
            str(e["n_queries"]),
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def write_markdown(path: str | Path, entries: Iterable[dict[str, Any]], title: str | None = None) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = (f"# {title}\n\n" if title else "") + markdown_table(entries)
    path.write_text(text)
    return path


def _save(fig: Figure, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    FigureCanvasAgg(fig)  # attaches an Agg canvas to the figure; no pyplot, no global backend
    fig.savefig(path, format="png", bbox_inches="tight")  # "tight" keeps the legend below the axes in the image
    return path


def _legend_below(ax: Any, n: int) -> None:
    # Below the axes, never over the curves: PR curves and F1 lines can run anywhere in the plot.
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=1 if n > 4 else 2, fontsize="small",
              frameon=False)


def plot_pr_curves(series: Sequence[tuple[str, PRCurve]], path: str | Path, title: str = "") -> Path:
    """Precision against recall, one line per (label, curve); the marker is each curve's max-F1 point."""
    if not series:
        raise InputError("no PR curves to plot")
    fig = Figure(figsize=(6.4, 5.2), dpi=120)
    ax = fig.add_subplot(1, 1, 1)
    for label, curve in series:
        if len(curve) == 0 or curve.n_positives == 0:
            ax.plot([], [], label=f"{label} (no accepted query)")
            continue
        # Start at recall 0 with the strictest point's precision so the line reaches the axis.
        recall = np.r_[0.0, curve.recall] * 100
        precision = np.r_[curve.precision[0], curve.precision] * 100
        style = "--" if "sequence" in label else "-"  # identical curves of two modes stay visible
        (line,) = ax.plot(recall, precision, style, label=label, linewidth=1.6)
        k = int(np.argmax(curve.f1))
        ax.plot([curve.recall[k] * 100], [curve.precision[k] * 100], "o", color=line.get_color(), markersize=5)
    ax.set_xlim(0, 100)
    ax.set_ylim(0, 102)
    ax.set_xlabel("recall (% of queries with a true match)")
    ax.set_ylabel("precision (%)")
    ax.grid(True, alpha=0.3)
    ax.set_title(title or "Precision-recall (dot: max F1)")
    _legend_below(ax, len(series))
    return _save(fig, path)


def plot_max_f1_vs_tolerance(
    series: Sequence[tuple[str, Sequence[Evaluation]]], path: str | Path, title: str = ""
) -> Path:
    """Max F1 against the localization radius (or frame tolerance): one line per (label, evaluations)."""
    if not series:
        raise InputError("no max-F1 series to plot")
    units = {e.unit for _, evals in series for e in evals}
    if len(units) != 1:
        raise InputError(f"max-F1 series mix tolerance units {sorted(units)}; plot one unit per figure")
    unit = units.pop()
    fig = Figure(figsize=(6.4, 4.8), dpi=120)
    ax = fig.add_subplot(1, 1, 1)
    for label, evals in series:
        tol, f1 = max_f1_by_tolerance(evals)
        ax.plot(tol, f1 * 100, "o-", label=label, linewidth=1.6, markersize=4)
    ax.set_xlabel(UNIT_LABELS.get(unit, unit))
    ax.set_ylabel("max F1 (%)")
    ax.set_ylim(0, 102)
    ax.grid(True, alpha=0.3)
    if unit == "frames":
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_title(title or "Max F1 against localization tolerance")
    _legend_below(ax, len(series))
    return _save(fig, path)
