"""``lostx listen ENDPOINT``: show the service's answers as a live table, or write them as JSON lines."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict
from pathlib import Path
from typing import IO, TYPE_CHECKING

from lostx.display import drop_line, state_label, warm_up_line
from lostx.options import add_client_key_options, client_keys_from_args, number, whole_number

if TYPE_CHECKING:
    from lostx.stream.protocol import ErrorMessage, Result, Stats

HEADER = f"{'frame':>7s}  {'state':<13s}  {'match':>6s}  {'name':<18s}  {'conf':>5s}  {'score':>9s}  {'seq':>8s}  {'ms':>6s}"


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("listen", help="show the answers of a running service")
    parser.add_argument("endpoint", help="the service's results endpoint, e.g. tcp://127.0.0.1:5556")
    parser.add_argument("--jsonl", type=Path, metavar="FILE",
                        help="write every message (result, error, stats) as a JSON line to FILE ('-': stdout)")
    parser.add_argument("--count", type=whole_number(1), metavar="N", help="exit after N results")
    parser.add_argument("--timeout", type=number(0, above=True), metavar="S",
                        help="exit after S seconds without any message")
    parser.add_argument("--until-stopped", action="store_true",
                        help="exit when the service announces it is stopping (its final stats)")
    parser.add_argument("--quiet", action="store_true", help="no table (with --jsonl FILE)")
    add_client_key_options(parser)
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from lostx.core.outputs import check_output_file
    from lostx.stream.client import Listener
    from lostx.stream.protocol import ErrorMessage, Result

    keys = client_keys_from_args(args)
    to_stdout = args.jsonl is not None and str(args.jsonl) == "-"
    table = not args.quiet and not to_stdout
    out: IO[str] | None = None
    if args.jsonl is not None:
        out = sys.stdout if to_stdout else open(check_output_file(args.jsonl, "--jsonl"), "a", encoding="utf-8")
    n_results = rows = warming = seen = 0
    last_stats: Stats | None = None
    try:
        with Listener(args.endpoint, keys=keys) as listener:
            if table:
                print(f"listening to {args.endpoint}", file=sys.stderr)
            while args.count is None or n_results < args.count:
                message = listener.receive(args.timeout)
                if message is None:
                    break
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
                        print(f"{where}: error {message.code}: {message.text}", flush=True)
                else:
                    if table and (last_stats is None or message.session != last_stats.session):
                        print(f"service session {message.session} ({message.mode} mode)", file=sys.stderr)
                    last_stats = message
                    if message.final and args.until_stopped:
                        break
    except KeyboardInterrupt:
        pass
    finally:
        if out is not None and not to_stdout:
            out.close()
    if table:
        print(f"{n_results} results" + (f"; service: {format_stats(last_stats)}" if last_stats else ""),
              file=sys.stderr)
        for line in (warm_up_line(warming, n_results, seen), drop_line(last_stats) if last_stats else None):
            if line:
                print(line, file=sys.stderr)
    return 0


def format_result(r: Result) -> str:
    score = "-" if r.score is None else f"{r.score:.4g}"
    seq = "-" if r.sequence_score is None else f"{r.sequence_score:.4g}"
    return (f"{r.frame_id:7d}  {state_label(r):<13s}  {r.match_index:6d}  {r.match_name[:18]:<18s}  "
            f"{r.confidence:5.2f}  {score:>9s}  {seq:>8s}  {r.latency_ms.get('total', 0.0):6.1f}")


def format_stats(s: Stats) -> str:
    step = s.latency_ms.get("step", {})
    p50 = f", step p50 {step['p50']:.0f} ms" if "p50" in step else ""
    return (f"received {s.received}, answered {s.answered}, dropped {s.dropped}, missing {s.missing}, "
            f"errors {s.errors}{p50}")


def _plain(message: Result | ErrorMessage | Stats) -> dict:
    from lostx.stream.protocol import ErrorMessage, Result

    if isinstance(message, Result):
        return {"type": "result", **message.to_dict()}
    if isinstance(message, ErrorMessage):
        return {"type": "error", **asdict(message)}
    return {"type": "stats", **asdict(message)}
