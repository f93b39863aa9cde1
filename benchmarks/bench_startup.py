"""Start-up time of the ``lostx`` command and the size of the installed environment.

    python benchmarks/bench_startup.py [--repeat 15] [--quick] [--out benchmarks/results/startup.json]

Times whole processes (interpreter start included) of ``lostx --help``,
``lostx --version`` and a sub-command's ``--help`` against a bare
``python -c pass`` and against importing what a real run needs (the localizer,
and torch for the PyTorch backbone), so the figures read as ratios taken in one
run. Then sums the installed packages of the running environment, largest
first. Prints tables; writes ``benchmarks/results/startup.json`` (or ``--out``).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from importlib import metadata
from pathlib import Path

from common import parse, print_table, summary, write_json

COMMANDS = {
    "python -c pass (the interpreter alone)": [sys.executable, "-c", "pass"],
    "lostx --help": [sys.executable, "-P", "-m", "lostx.cli", "--help"],
    "lostx --version": [sys.executable, "-P", "-m", "lostx.cli", "--version"],
    "lostx match --help": [sys.executable, "-P", "-m", "lostx.cli", "match", "--help"],
    "import the localizer (what a run loads)": [sys.executable, "-P", "-c", "import lostx.core.localizer"],
    "import torch (PyTorch backbones only)": [sys.executable, "-P", "-c", "import torch"],
}


def time_process(argv: list[str], repeat: int) -> list[float] | None:
    """Milliseconds per run; None when the command fails (torch not installed)."""
    if subprocess.run(argv, capture_output=True).returncode != 0:  # also warms the file cache
        return None
    samples = []
    for _ in range(repeat):
        start = time.perf_counter()
        subprocess.run(argv, capture_output=True, check=True)
        samples.append(1e3 * (time.perf_counter() - start))
    return samples


def package_sizes() -> list[tuple[str, int]]:
    """Bytes on disk of every installed distribution's files, largest first."""
    sizes = []
    for dist in metadata.distributions():
        total = 0
        for file in dist.files or ():
            path = Path(dist.locate_file(file))
            if path.is_file():
                total += path.stat().st_size
        sizes.append((dist.metadata["Name"], total))
    return sorted(sizes, key=lambda item: -item[1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=15)
    args = parse(parser, "startup", quick="2 runs of each command")
    if args.quick:
        args.repeat = 2

    measured = {name: time_process(argv, args.repeat) for name, argv in COMMANDS.items()}
    timings = {name: summary(samples) for name, samples in measured.items() if samples is not None}
    base = timings["lostx --help"]["median_ms"]
    print_table("start-up, whole process (ms)", ["command", "median", "p90", "x lostx --help"],
                [[name, t["median_ms"], t["p90_ms"], t["median_ms"] / base] for name, t in timings.items()])

    sizes = package_sizes()
    total = sum(size for _, size in sizes)
    print_table(f"installed packages: {total / 1e6:.0f} MB in all", ["package", "MB", "share %"],
                [[name, size / 1e6, 100 * size / total] for name, size in sizes[:10]])
    write_json(args.out, {
        "repeat": args.repeat,
        "startup_ms": timings,
        "installed_bytes": total,
        "packages_bytes": dict(sizes),
    })


if __name__ == "__main__":
    main()
