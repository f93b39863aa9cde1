"""``lostx listen ENDPOINT``: show the service's answers as a live table, or write them as JSON lines.

With ``--jsonl FILE --resume`` it picks up where an earlier run writing FILE stopped: every answer
the service's journal holds after the last one in FILE is appended first, once and in order."""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import asdict
from pathlib import Path
from typing import IO, TYPE_CHECKING

from lostx.display import drop_line, state_label, warm_up_line
from lostx.options import add_client_key_options, client_keys_from_args, number, whole_number

if TYPE_CHECKING:
    from lostx.stream.client import Listener
    from lostx.stream.messages import ErrorMessage, Result, Stats

HEADER = (f"{'stream':<10s}  {'frame':>7s}  {'state':<13s}  {'match':>6s}  {'name':<18s}  {'conf':>5s}  {'score':>9s}  "
          f"{'seq':>8s}  {'ms':>6s}")


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("listen", help="show the answers of a running service")
    parser.add_argument("endpoint", help="the service's results endpoint, e.g. tcp://127.0.0.1:5556")
    parser.add_argument("--jsonl", type=Path, metavar="FILE",
                        help="write every message (result, error, stats) as a JSON line to FILE ('-': stdout)")
    parser.add_argument("--count", type=whole_number(1), metavar="N", help="exit after N results")
    parser.add_argument("--timeout", type=number(0, above=True), metavar="S",
                        help="exit after S seconds without an answer (the service's stats do not count); "
                             "an error if nothing at all was heard from a service")
    parser.add_argument("--until-stopped", action="store_true",
                        help="exit when the service announces it is stopping (its final stats)")
    parser.add_argument("--quiet", action="store_true", help="no table (with --jsonl FILE)")
    journal = parser.add_argument_group("resuming (from a service with a journal)")
    start = journal.add_mutually_exclusive_group()
    start.add_argument("--resume", action="store_true",
                       help="continue after the last answer in the --jsonl FILE (all the journal holds if FILE "
                            "is new)")
    start.add_argument("--after", type=whole_number(0), metavar="SEQ",
                       help="first hand over the answers numbered above SEQ")
    journal.add_argument("--history", metavar="ENDPOINT",
                         help="the service's history endpoint (default: the results port plus one)")
    add_client_key_options(parser)
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from lostx.core.errors import InputError
    from lostx.core.outputs import check_output_file
    from lostx.stream.client import Listener
    from lostx.stream.errors import StreamError
    from lostx.stream.messages import ErrorMessage, Result

    keys = client_keys_from_args(args)
    to_stdout = args.jsonl is not None and str(args.jsonl) == "-"
    if args.resume and (args.jsonl is None or to_stdout):
        raise InputError("--resume continues a --jsonl FILE: give the file")
    if args.jsonl is not None and not to_stdout:
        check_output_file(args.jsonl, "--jsonl")
    after, journal = args.after, None
    if args.resume:
        after, journal = resume_point(args.jsonl)
    table = not args.quiet and not to_stdout
    out: IO[str] | None = None
    if args.jsonl is not None:
        out = sys.stdout if to_stdout else open(args.jsonl, "a", encoding="utf-8")
    n_results = rows = warming = seen = 0
    heard = interrupted = False
    last_stats: Stats | None = None
    listener: Listener | None = None
    try:
        with Listener(args.endpoint, keys=keys, history=args.history, after=after, journal=journal) as listener:
            if table:
                resuming = f", resuming after answer {after}" if after is not None else ""
                print(f"listening to {args.endpoint}{resuming}", file=sys.stderr)
            quiet_until = None if args.timeout is None else time.monotonic() + args.timeout
            while args.count is None or n_results < args.count:
                wait = None if quiet_until is None else max(0.0, quiet_until - time.monotonic())
                message = listener.receive(wait)
                while listener.notices:
                    print(f"lostx listen: {listener.notices.popleft()}", file=sys.stderr)
                if message is None:
                    break
                heard = True
                answer = isinstance(message, Result) or isinstance(message, ErrorMessage) and message.tag is not None
                if quiet_until is not None and answer:
                    quiet_until = time.monotonic() + args.timeout
                if out is not None:
                    out.write(json.dumps(_plain(message)) + "\n")
                    out.flush()
                if isinstance(message, Result):
                    n_results += 1
                    warming += message.warming_up
                    seen = max(seen, message.window)
                    if table:
                        if rows % 40 == 0:
                            print(HEADER)
                        print(format_result(message), flush=True)
                        rows += 1
                elif isinstance(message, ErrorMessage):
                    if table:
                        where = f"frame {message.frame_id}" if message.frame_id is not None else "message"
                        stream = f"stream {message.tag.stream!r} " if message.tag is not None else ""
                        print(f"{stream}{where}: error {message.code}: {message.text}", flush=True)
                else:
                    if table and (last_stats is None or message.session != last_stats.session):
                        print(f"service session {message.session} ({message.mode} mode)", file=sys.stderr)
                    last_stats = message
                    if message.final and args.until_stopped:
                        break
    except KeyboardInterrupt:
        interrupted = True
    finally:
        if out is not None and not to_stdout:
            out.close()
    if not heard and args.timeout is not None and not interrupted:
        raise StreamError(f"no service answered at {args.endpoint} within {args.timeout:g} s")
    line = f"{n_results} results"
    if listener is not None:
        line += summary(listener)
    if last_stats is not None:
        line += f"; service: {format_stats(last_stats)}"
    if table or listener is not None and listener.missed:
        print(line, file=sys.stderr)
    if table:
        for extra in (warm_up_line(warming, n_results, seen), drop_line(last_stats) if last_stats else None):
            if extra:
                print(extra, file=sys.stderr)
    return 0


def resume_point(path: Path) -> tuple[int, str | None]:
    """The sequence number and journal of the last answer in a JSON-lines file written by ``lostx listen``
    (0 where it holds none). A last line cut short (the listener was killed while writing it) is removed."""
    from lostx.core.errors import InputError

    if not path.exists():
        return 0, None
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc.strerror}") from None
    end = data.rfind(b"\n") + 1
    if end < len(data):
        os.truncate(path, end)
    for line in reversed(data[:end].splitlines()):
        try:
            row = json.loads(line)
        except ValueError:
            raise InputError(f"{path} is not a lostx listen JSON-lines file (a line is not JSON)") from None
        if isinstance(row, dict) and isinstance(row.get("seq"), int) and row.get("type") in ("result", "error"):
            return row["seq"], row.get("journal")
    return 0, None


def summary(listener: Listener) -> str:
    parts = []
    if listener.recovered:
        parts.append(f"{listener.recovered} recovered from the journal")
    if listener.missed:
        parts.append(f"{listener.missed} MISSED (this listener fell behind; see the notices above)")
    if listener.duplicates:
        parts.append(f"{listener.duplicates} duplicates skipped")
    return "".join(f"; {p}" for p in parts)


def format_result(r: Result) -> str:
    score = "-" if r.score is None else f"{r.score:.4g}"
    return (f"{r.tag.stream[:10]:<10s}  {r.frame_id:7d}  {state_label(r):<13s}  {r.match_index:6d}  "
            f"{r.match_name[:18]:<18s}  {r.confidence:5.2f}  {score:>9s}  {r.tag.seq:8d}  "
            f"{r.latency_ms.get('total', 0.0):6.1f}")


def format_stats(s: Stats) -> str:
    step = s.latency_ms.get("step", {})
    p50 = f", step p50 {step['p50']:.0f} ms" if "p50" in step else ""
    return (f"received {s.received}, answered {s.answered}, dropped {s.dropped}, missing {s.missing}, "
            f"errors {s.errors}, {len(s.streams)} stream(s){p50}")


def _plain(message: Result | ErrorMessage | Stats) -> dict:
    from lostx.stream.messages import ErrorMessage, Result

    if isinstance(message, Result):
        return {"type": "result", **message.to_dict()}
    if isinstance(message, ErrorMessage):
        data = asdict(message)
        data.update(data.pop("tag") or {})
        return {"type": "error", **data}
    return {"type": "stats", **asdict(message)}
