"""The ``lostx`` command: a thin layer over the Python API.

Each sub-command lives in ``lostx/commands/<name>.py`` with a ``register``
function. Command modules import only the standard library at the top (the
heavy libraries load inside ``run``), so ``lostx --help`` starts at once.
Errors on bad input are one line on stderr and a non-zero exit code.
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
from typing import NoReturn  # noqa: E402

from lostx import __version__  # noqa: E402
from lostx.core.errors import LostxError  # noqa: E402
from lostx.options import stop_signals_as_interrupt  # noqa: E402
from lostx.stream.processes import exit_with_parent  # noqa: E402

COMMANDS = ("demo", "map", "match", "eval", "serve", "ros2", "replay", "listen", "keys", "backbones", "camera")


class Parser(argparse.ArgumentParser):
    """argparse with usage errors on one line (``lostx: error: ...``) instead of a usage block."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"lostx: error: {message} (see '{self.prog} --help')\n")


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="lostx",
        description="Streaming LoST-X place recognition: opposite viewpoints, day and night.",
        epilog="Run 'lostx COMMAND --help' for a command's options.",
    )
    parser.add_argument("--version", action="version", version=f"lostx {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", title="commands")
    for name in COMMANDS:
        importlib.import_module(f"lostx.commands.{name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    exit_with_parent()  # started by a lostx process (the demo, a test): do not outlive it
    parser = build_parser()
    args, unknown = parser.parse_known_args(argv)
    if unknown:
        command = " ".join(filter(None, ("lostx", args.command, getattr(args, "verb", None))))
        parser.exit(2, f"lostx: error: unrecognized arguments: {' '.join(unknown)} (see '{command} --help')\n")
    if args.command is None:
        parser.print_help()
        return 2
    args.command_line = ["lostx", *(sys.argv[1:] if argv is None else argv)]
    warnings.showwarning = _show_warning
    try:
        # SIGTERM and SIGHUP, like Ctrl-C, end a command through its cleanup: no child outlives it.
        with stop_signals_as_interrupt():
            return int(args.run(args) or 0)
    except LostxError as exc:
        return _fail(str(exc))
    except BrokenPipeError:
        # The reader of the output went away (`lostx map info MAP | head -3`): nothing more to say, and
        # Python's own flush at exit must not complain either.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as exc:
        # A file the command had to write or read failed under it (disk full, permissions): say which.
        return _fail(f"{exc.strerror or exc}: {exc.filename}" if exc.filename else str(exc))
    except KeyboardInterrupt as exc:
        _close_progress_bars()
        # A command may say what it kept and how to go on (the exception's message).
        print(f"lostx: interrupted{f': {exc}' if str(exc) else ''}", file=sys.stderr)
        return 130


def _fail(message: str) -> int:
    _close_progress_bars()
    print(f"lostx: error: {message}", file=sys.stderr)
    return 2


def _close_progress_bars() -> None:
    """Clear any progress bar still drawn, so a message starts on a line of its own."""
    tqdm = sys.modules.get("tqdm")
    if tqdm is not None:
        for bar in list(getattr(tqdm.tqdm, "_instances", ())):
            bar.close()


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:  # noqa: ANN001
    """Warnings printed above any progress bar: lostx's own as one line, ``lostx: warning: ...``; those of
    other libraries as Python shows them (with where they come from)."""
    if category.__module__.startswith("lostx."):
        text = f"lostx: warning: {message}"
    else:
        text = warnings.formatwarning(message, category, filename, lineno, line).rstrip("\n")
    tqdm = sys.modules.get("tqdm")
    if tqdm is not None:
        tqdm.tqdm.write(text, file=sys.stderr)
    else:
        print(text, file=sys.stderr)


if __name__ == "__main__":
    sys.exit(main())
