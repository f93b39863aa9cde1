"""Evaluation reports: ``report.json``, ``report.md`` (settings, table, figures), and PNG figures
(PR curves, max F1 against the tolerance).

The table's columns are :data:`TABLE_COLUMNS` (add one there and every report
has it). In the figures a method keeps one colour, solid for its single-frame
line and dashed for its sequence line. Figures are drawn on Matplotlib's Agg
canvas directly (no pyplot), so importing this module never changes the
backend of a program that also shows windows.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, Literal, Sequence

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import to_rgb
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from lostx.core.errors import InputError
from .catalogue import MODES
from .metrics import Evaluation, PRCurve, max_f1_by_tolerance
from .significance import PairedComparison

Mode = Literal["single", "sequence"]
REQUIRED_KEYS = (
    "method", "mode", "tolerance", "tolerance_unit", "recall_at_100p", "max_f1", "auc_pr",
    "recall_at_1", "recall_at_5", "recall_at_10", "n_queries",
)
UNIT_LABELS = {"m": "localization radius (m)", "frames": "tolerance (frames)"}


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


def quantity(value: float, unit: str) -> str:
    """A tolerance with its unit: ``0 frames``, ``1 frame``, ``2.5 m``."""
    return f"{value:g} {'frame' if unit == 'frames' and value == 1 else unit}"


def _percent(key: str) -> Callable[[dict[str, Any]], str]:
    return lambda entry: _fmt(entry[key], True)


def _recalled(entry: dict[str, Any]) -> str:
    """Recall@1 as a count of its denominator: ``27/34``."""
    if not entry.get("recall_denominator"):
        return "n/a"
    return f"{entry['n_recalled_at_1']}/{entry['recall_denominator']}"


def _interval(entry: dict[str, Any]) -> str:
    """Recall@1's 95 % interval in percent: ``63-90``."""
    low, high = entry.get("recall_at_1_low", float("nan")), entry.get("recall_at_1_high", float("nan"))
    if not (math.isfinite(float(low)) and math.isfinite(float(high))):
        return "n/a"
    return f"{100 * low:.0f}-{100 * high:.0f}"


TABLE_COLUMNS: list[tuple[str, Callable[[dict[str, Any]], str]]] = [
    ("method", lambda e: str(e["method"])),
    ("mode", lambda e: str(e["mode"])),
    ("tolerance", lambda e: quantity(e["tolerance"], e["tolerance_unit"])),
    ("R@100P oracle %", _percent("recall_at_100p")),
    ("localized", lambda e: str(e.get("localized", "n/a"))),
    ("localized prec. %", lambda e: _fmt(e.get("localized_precision", float("nan")), True)),
    ("localized recall %", lambda e: _fmt(e.get("localized_recall", float("nan")), True)),
    ("max F1 %", _percent("max_f1")),
    ("AUC-PR %", _percent("auc_pr")),
    ("R@1 %", _percent("recall_at_1")),
    ("R@1 right", _recalled),
    ("R@1 95 % interval", _interval),
    ("R@5 %", _percent("recall_at_5")),
    ("R@10 %", _percent("recall_at_10")),
    ("heading right %", lambda e: _fmt(e.get("heading_right", float("nan")), True)),
    ("queries", lambda e: str(e["n_queries"])),
]
"""The markdown table: (header, cell of an entry); the first two columns are text, the rest numbers."""


ORACLE_AND_DEPLOYED = (
    "*R@100P oracle*: recall at 100 % precision with the best threshold chosen after seeing the answers "
    "(what a PR curve shows; a robot cannot). *localized*: the answers the localizer marked `localized`, "
    "with the threshold it fixed beforehand (calibrated on the map): their precision and recall are what a "
    "deployed system gets.\n\n"
)
INTERVAL_NOTE = (
    "*R@1 right*: the queries recalled at the first answer, of those counted. *R@1 95 % interval*: the Wilson score "
    "interval of that share: on few queries a recall is known only this well.\n\n"
)
PAIRED_NOTE = (
    "Two sets of answers to the same queries: the queries only each gets right, and the exact McNemar test's "
    "p-value (the chance of a split at least this uneven were both equally good). A split of a few queries is "
    "noise. Neighbouring answers are not independent (a sequence filter's share its window; a layout's grids share "
    "their frames), so the split is also counted in stretches, each run of neighbouring queries only one gets right "
    "counted once: the p-value of the queries overstates the evidence, that of the stretches understates it.\n\n"
)
RELIABILITY_NOTE = (
    "Answers binned by their confidence, and the share of each bin that is right (at the tightest tolerance). "
    "A confidence that means what it says has a precision at least as high as the bin's confidences.\n\n"
)


def markdown_table(entries: Iterable[dict[str, Any]]) -> str:
    """A GitHub markdown table of the entries; rates in percent, 'n/a' where undefined."""
    header = [name for name, _ in TABLE_COLUMNS]
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(["---"] * 2 + ["---:"] * (len(header) - 2)) + "|"]
    for entry in entries:
        lines.append("| " + " | ".join(cell(entry) for _, cell in TABLE_COLUMNS) + " |")
    return "\n".join(lines) + "\n"


def paired_table(rows: Sequence[tuple[str, str, str, PairedComparison, PairedComparison]]) -> str:
    """``(first, second, tolerance, by query, by stretch)`` per pair of answers to the same queries: the queries only
    each gets right and the exact McNemar test's p-value, and the same counting each stretch of neighbouring queries
    once."""
    if not rows:
        return ""
    lines = ["| answers | against | tolerance | right only here | right only there | p "
             "| in stretches: here, there, p |",
             "|---|---|---|---:|---:|---:|---:|"]
    for first, second, tolerance, c, runs in rows:
        lines.append(f"| {first} | {second} | {tolerance} | {c.only_first} | {c.only_second} | {c.p_value:.2g} | "
                     f"{runs.only_first}, {runs.only_second}, {runs.p_value:.2g} |")
    return "\n".join(lines) + "\n"


def reliability_table(rows: Sequence[tuple[str, Sequence[Any]]]) -> str:
    """``(label, bins)`` per method and mode: answers and measured precision in each confidence bin."""
    if not rows:
        return ""
    bins = rows[0][1]
    header = ["method"] + [f"[{b.low:g}, {b.high:g}{']' if i == len(bins) - 1 else ')'}" for i, b in enumerate(bins)]
    lines = ["| " + " | ".join(header) + " |", "|---|" + "|".join(["---:"] * len(bins)) + "|"]
    for label, row in rows:
        cells = [f"{_fmt(b.precision, True)} % of {b.n}" if b.n else "-" for b in row]
        lines.append("| " + " | ".join([label] + cells) + " |")
    return "\n".join(lines) + "\n"


def write_markdown(path: str | Path, entries: Iterable[dict[str, Any]], title: str | None = None,
                   settings: dict[str, Any] | None = None, figures: Sequence[tuple[str, str | Path]] = (),
                   reliability: str = "", comparisons: str = "") -> Path:
    """``report.md``: the title, the settings that produced the numbers, the table, the answers compared query by
    query (:func:`paired_table`), the reliability of the confidence, and the figures (``(caption, file)``, linked
    relative to the report)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    parts = [f"# {title}\n"] if title else []
    if settings:
        rows = "".join(f"| {key} | {value} |\n" for key, value in settings.items())
        parts.append(f"## Settings\n\n| setting | value |\n|---|---|\n{rows}")
    parts.append(("## Results\n\n" if settings or figures else "") + ORACLE_AND_DEPLOYED + INTERVAL_NOTE
                 + markdown_table(entries))
    if comparisons:
        parts.append("## Differences, query by query\n\n" + PAIRED_NOTE + comparisons)
    if reliability:
        parts.append("## Reliability of the confidence\n\n" + RELIABILITY_NOTE + reliability)
    if figures:
        parts.append("## Figures\n\n" + "\n".join(
            f"![{caption}]({Path(file).relative_to(path.parent) if Path(file).is_absolute() else file})\n"
            for caption, file in figures))
    path.write_text("\n".join(parts))
    return path


@dataclass(frozen=True)
class LineStyle:
    """How one line of a figure is drawn."""

    colour: Any
    dashes: str = "-"
    width: float = 1.6
    layer: int = 2
    """Matplotlib z-order: narrower lines are drawn over wider ones."""


MODE_DASHES = {"single": "-", "sequence": "--"}


def method_styles(lines: Sequence[tuple[str, str]]) -> list[LineStyle]:
    """Styles for ``(method, mode)`` lines: one hue per method, a solid single-frame line and a narrower,
    lighter, dashed sequence line drawn over it. Earlier methods are drawn wider, so lines lying on one
    another (two perfect methods, or a method's two modes) stay visible."""
    methods = list(dict.fromkeys(method for method, _ in lines))
    styles = []
    for method, mode in lines:
        rank = methods.index(method)
        width = 1.6 + 0.9 * (len(methods) - 1 - rank)
        colour = to_rgb(f"C{rank % 10}")
        if mode == "single":
            styles.append(LineStyle(colour, MODE_DASHES["single"], width, layer=2 + rank))
        else:
            lighter = tuple(c + (1 - c) * 0.45 for c in colour)
            styles.append(LineStyle(lighter, MODE_DASHES.get(mode, ":"), max(1.2, 0.5 * width), layer=10 + rank))
    return styles


def _default_styles(n: int) -> list[LineStyle]:
    return [LineStyle(f"C{i % 10}") for i in range(n)]


def _save(fig: Figure, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    FigureCanvasAgg(fig)  # attaches an Agg canvas to the figure; no pyplot, no global backend
    fig.savefig(path, format="png", bbox_inches="tight")  # "tight" keeps the legend below the axes in the image
    return path


def _percent_axis(axis: Any) -> None:
    # A margin beyond 0 and 100 %: a perfect curve runs inside the frame, not hidden under its border.
    axis.set_ticks(np.arange(0, 101, 20))


def _legend_below(ax: Any, n: int, marker_meaning: str) -> None:
    # Below the axes, never over the curves: PR curves and F1 lines can run anywhere in the plot.
    ax.plot([], [], "o", color="0.6", markeredgecolor="0.2", markeredgewidth=0.6, markersize=5, label=marker_meaning)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=1 if n > 4 else 2, fontsize="small",
              frameon=False)


def pr_line(curve: PRCurve) -> tuple[np.ndarray, np.ndarray]:
    """The (recall %, precision %) points of a PR curve as drawn: those at recall 0 are left out, since
    precision there only says whether the most confident answers were wrong (a line from (0, 0) reads
    as a curve that starts at zero precision)."""
    shown = curve.recall > 0
    return curve.recall[shown] * 100, curve.precision[shown] * 100


def plot_pr_curves(series: Sequence[tuple[str, PRCurve]], path: str | Path, title: str = "",
                   styles: Sequence[LineStyle] | None = None) -> Path:
    """Precision against recall (:func:`pr_line`), one line per (label, curve); the dot marks each
    curve's max-F1 point."""
    if not series:
        raise InputError("no PR curves to plot")
    styles = list(styles) if styles is not None else _default_styles(len(series))
    fig = Figure(figsize=(6.4, 5.4), dpi=120)
    ax = fig.add_subplot(1, 1, 1)
    for (label, curve), style in zip(series, styles):
        recall, precision = pr_line(curve)
        if not len(recall):
            ax.plot([], [], style.dashes, color=style.colour, label=f"{label} (no correct answer)")
            continue
        ax.plot(recall, precision, style.dashes, color=style.colour, linewidth=style.width, label=label,
                marker="." if len(recall) == 1 else "", zorder=style.layer)
        k = int(np.argmax(curve.f1))
        ax.plot([curve.recall[k] * 100], [curve.precision[k] * 100], "o", color=style.colour, markersize=5,
                markeredgecolor="0.2", markeredgewidth=0.6, zorder=20)
    ax.set_xlim(-3, 103)
    ax.set_ylim(-3, 103)
    _percent_axis(ax.xaxis)
    _percent_axis(ax.yaxis)
    ax.set_xlabel("recall (% of queries with a true match)")
    ax.set_ylabel("precision (%)")
    ax.grid(True, alpha=0.3)
    ax.set_title(title or "Precision-recall")
    _legend_below(ax, len(series) + 1, "max F1 of the line")
    return _save(fig, path)


def plot_max_f1_vs_tolerance(
    series: Sequence[tuple[str, Sequence[Evaluation]]], path: str | Path, title: str = "",
    styles: Sequence[LineStyle] | None = None,
) -> Path:
    """Max F1 against the localization radius (or frame tolerance): one line per (label, evaluations),
    a dot at each tolerance evaluated."""
    if not series:
        raise InputError("no max-F1 series to plot")
    units = {e.unit for _, evals in series for e in evals}
    if len(units) != 1:
        raise InputError(f"max-F1 series mix tolerance units {sorted(units)}; plot one unit per figure")
    unit = units.pop()
    styles = list(styles) if styles is not None else _default_styles(len(series))
    fig = Figure(figsize=(6.4, 5.0), dpi=120)
    ax = fig.add_subplot(1, 1, 1)
    for (label, evals), style in zip(series, styles):
        tol, f1 = max_f1_by_tolerance(evals)
        ax.plot(tol, f1 * 100, style.dashes, color=style.colour, linewidth=style.width, label=label,
                marker="o", markersize=4, markeredgecolor="0.2", markeredgewidth=0.6, zorder=style.layer)
    ax.set_xlabel(UNIT_LABELS.get(unit, unit))
    ax.set_ylabel("max F1 (%)")
    ax.set_ylim(-3, 103)
    _percent_axis(ax.yaxis)
    ax.margins(x=0.04)
    ax.grid(True, alpha=0.3)
    if unit == "frames":
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_title(title or "Max F1 against localization tolerance")
    _legend_below(ax, len(series) + 1, "a tolerance evaluated")
    return _save(fig, path)
