"""The ``lostx`` command: a thin layer over the Python API.

Each sub-command lives in ``lostx/commands/<name>.py`` with a ``register``
function. Errors on bad input are one line on stderr and a non-zero exit code.
"""

from __future__ import annotations

import os

# numpy's BLAS threads spin after each of the localizer's small matrix products and take the cores
# from the network: one BLAS thread makes MOSAIC 1.8x faster (73.6 -> 41.2 ms per frame measured on
# 2 cores). Set before numpy loads; the child processes of `lostx demo` inherit it.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import importlib  # noqa: E402
import sys  # noqa: E402
import warnings  # noqa: E402

from lostx import __version__  # noqa: E402
from lostx.core.errors import LostxError  # noqa: E402
from lostx.stream.processes import exit_with_parent

COMMANDS = ("demo", "map", "match", "eval", "serve", "replay", "listen", "keys", "backbones")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="lostx",
        description="Streaming LoST-X place recognition: opposite viewpoints, day and night.",
    )
    parser.add_argument("--version", action="version", version=f"lostx {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS:
        importlib.import_module(f"lostx.commands.{name}").register(sub)
    return parser


def show_warning(message, category, filename, lineno, file=None, line=None) -> None:  # noqa: ANN001
    """lostx's own warnings as one line, ``lostx: warning: ...``, above any progress bar; others as Python shows them."""
    if not category.__module__.startswith("lostx."):
        _python_show_warning(message, category, filename, lineno, file, line)
        return
    from tqdm import tqdm

    tqdm.write(f"lostx: warning: {message}", file=sys.stderr)


_python_show_warning = warnings.showwarning


def main(argv: list[str] | None = None) -> int:
    exit_with_parent()  # started by a lostx process (the demo, a test): do not outlive it
    warnings.showwarning = show_warning
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.run(args) or 0)
    except LostxError as exc:
        print(f"lostx: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("lostx: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
