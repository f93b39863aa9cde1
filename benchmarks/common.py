"""Helpers shared by the benchmarks: options, timing, tables, JSON output."""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the lostx command does (lostx/cli.py)

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any, Callable  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"


def parse(parser: argparse.ArgumentParser, name: str, quick: str, argv: list[str] | None = None) -> argparse.Namespace:
    """The options every benchmark takes, then its arguments: ``--quick`` (``quick`` says what it then runs) and
    ``--out``. A quick run's JSON goes to ``NAME-quick.json`` unless told, so that a check that the benchmark
    runs never replaces its measured figures in ``NAME.json``."""
    parser.add_argument("--quick", action="store_true", help=f"{quick}: a check that it runs, in seconds")
    parser.add_argument("--out", type=Path, help=f"where the JSON goes (default: benchmarks/results/{name}.json; "
                                                 f"{name}-quick.json with --quick)")
    args = parser.parse_args(argv)
    if args.out is None:
        args.out = RESULTS / (f"{name}-quick.json" if args.quick else f"{name}.json")
    return args


def time_call(fn: Callable[[], Any], repeat: int, warmup: int = 2) -> list[float]:
    """Wall-clock milliseconds of ``repeat`` calls after ``warmup`` untimed ones."""
    for _ in range(warmup):
        fn()
    samples = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        samples.append(1e3 * (time.perf_counter() - start))
    return samples


def summary(samples: list[float]) -> dict[str, float]:
    ordered = sorted(samples)
    return {
        "median_ms": statistics.median(ordered),
        "p90_ms": ordered[min(len(ordered) - 1, int(0.9 * len(ordered)))],
        "mean_ms": statistics.fmean(ordered),
        "n": len(ordered),
    }


def print_table(title: str, header: list[str], rows: list[list[Any]]) -> None:
    cells = [header] + [[f"{v:.3g}" if isinstance(v, float) else str(v) for v in row] for row in rows]
    widths = [max(len(row[i]) for row in cells) for i in range(len(header))]
    print(f"\n{title}")
    for i, row in enumerate(cells):
        print("  ".join(cell.rjust(w) for cell, w in zip(row, widths)))
        if i == 0:
            print("  ".join("-" * w for w in widths))


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process (all its threads) so far."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def write_json(path: Path, payload: dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {"machine": {"python": platform.python_version(), "cpu": platform.processor() or platform.machine()},
               **payload}
    path.write_text(json.dumps(payload, indent=1))
    print(f"\nwrote {path}")


def markdown_table(title: str, header: list[str], rows: list[list[Any]]) -> str:
    """The table :func:`print_table` prints, as Markdown (for the study reports kept in benchmarks/results)."""
    cells = [[f"{v:.3g}" if isinstance(v, float) else str(v) for v in row] for row in rows]
    lines = [f"**{title}**", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in cells]
    return "\n".join(lines) + "\n"
