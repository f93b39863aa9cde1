"""``lostx serve --map MAP``: the localizer service (frames in, results out, over ZeroMQ).

It answers like ``lostx match --sequence``: the sequence filter and the tracker run unless
``--no-sequence`` or ``--no-tracker`` (or the ``--config`` file) turn them off."""

from __future__ import annotations

import argparse
import dataclasses
import signal
from pathlib import Path
from typing import TYPE_CHECKING

from lostx.display import drop_line
from lostx.options import (
    add_config_options,
    add_stream_options,
    add_viewer_options,
    config_from_args,
    stream_config_from_args,
    viewer_sink_from_args,
)

if TYPE_CHECKING:
    from lostx.stream.service import LocalizerService


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("serve", help="run the localizer as a ZeroMQ service (see docs/protocol.md)")
    parser.add_argument("--map", type=Path, required=True, help="reference map folder (from `lostx map build`)")
    add_stream_options(parser)
    out = parser.add_argument_group("sinks")
    out.add_argument("--jsonl", type=Path, metavar="FILE", help="also append every answer to FILE as JSON lines")
    out.add_argument("--sink", action="append", default=[], metavar="NAME[=ARG]",
                     help="hand every answer to a sink: jsonl=FILE, or package.module:factory[=ARG] (repeatable)")
    sec = parser.add_argument_group("security")
    sec.add_argument("--curve-secret", type=Path, metavar="FILE",
                     help="the service's secret key (.key_secret from `lostx keys`): CurveZMQ on all its sockets")
    sec.add_argument("--curve-clients", type=Path, metavar="DIR",
                     help="folder of the public keys (.key) of the producers and listeners allowed in")
    sec.add_argument("--insecure", action="store_true",
                     help="allow binding a non-loopback address without CurveZMQ (trusted networks only)")
    add_config_options(parser)
    parser.add_argument("--no-sequence", action="store_true",
                        help="answer each frame on its own, without the sequence filter and tracker "
                             "(as `lostx match` without --sequence)")
    add_viewer_options(parser)
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from lostx.core.budget import check_memory, state_bytes
    from lostx.core.errors import InputError
    from lostx.core.outputs import check_output_file, check_output_folder
    from lostx.core.maps.refmap import ReferenceMap
    from lostx.sinks import resolve_sink
    from lostx.stream.service import LocalizerService
    from lostx.stream.sinks import JsonlSink
    from lostx.stream.sockets import ServerKeys
    from lostx.stream.states import journal_space
    from lostx.stream.streams import localizer_factory

    stop = _SignalStop()
    with stop:
        config = stream_config_from_args(args, config_from_args(args))
        if args.no_sequence:
            config = dataclasses.replace(config, sequence=dataclasses.replace(config.sequence, enabled=False))
        if args.history and config.stream.journal is None:
            raise InputError("--history serves the journal: give --journal DIR too")
        if config.stream.mode == "lossless" and config.stream.journal is None and not args.no_journal:
            raise InputError("lossless mode needs a result journal: give --journal DIR (or --no-journal, and answers "
                             "a listener had not read when it died are lost)")
        if args.jsonl:
            check_output_file(args.jsonl, "--jsonl")
        if config.stream.journal is not None:
            check_output_folder(config.stream.journal, "--journal" if args.journal is not None else "[stream] journal")
        keys = None
        if args.curve_secret or args.curve_clients:
            if not (args.curve_secret and args.curve_clients):
                raise InputError("CurveZMQ needs both --curve-secret and --curve-clients")
            keys = ServerKeys(args.curve_secret, args.curve_clients)
        refmap = ReferenceMap.open(args.map)
        check_memory(config, refmap.n_frames, config.stream.max_streams, streams_setting="[stream] max_streams "
                     "(--max-streams)")
        if config.stream.journal is not None:
            short = journal_space(config.stream, state_bytes(config, refmap.n_frames))
            if short is not None:
                _warn(short)
        new_localizer = localizer_factory(refmap, config)
        sinks = [resolve_sink(spec) for spec in args.sink]
        if args.jsonl:
            sinks.append(JsonlSink(args.jsonl))
        viewer = viewer_sink_from_args(args, refmap)
        if viewer is not None:
            sinks.append(viewer)
        service = LocalizerService(new_localizer, config.stream, sinks=sinks, keys=keys, insecure=args.insecure)
        stop.attach(service)
        with service:
            final = service.run()
    journal = f"; journal holds answers {final.journal.first}-{final.journal.last}" if final.journal else ""
    service.log(f"answered {final.answered} of {final.received} frames ({final.dropped} dropped, "
                f"{final.missing} missing, {final.errors} errors) from {service.streams.created} stream(s) "
                f"in {final.uptime_s:.1f} s{journal}")
    dropped = drop_line(final)
    if dropped:
        service.log(dropped)
    return 0


def _warn(text: str) -> None:
    import sys

    print(f"lostx: warning: {text}", file=sys.stderr, flush=True)


class _SignalStop:
    """SIGINT/SIGTERM stop the service gracefully: the frame in hand is finished and flushed.

    Installed before the map loads. While the service is starting (the map opening, its calibration measured,
    the network loaded) there is nothing to finish: a signal then interrupts the start at once, wherever it is
    (``lostx: interrupted``, exit status 130)."""

    def __init__(self) -> None:
        self.service: LocalizerService | None = None
        self.signal_name: str | None = None
        self._previous: dict[int, object] = {}

    def attach(self, service: LocalizerService) -> None:
        self.service = service
        if self.signal_name is not None:
            service.stop(self.signal_name)

    def _on_signal(self, signum: int, _frame: object) -> None:
        self.signal_name = signal.Signals(signum).name
        if self.service is None:
            raise KeyboardInterrupt(f"{self.signal_name} while starting; nothing was served")
        self.service.stop(self.signal_name)

    def __enter__(self) -> "_SignalStop":
        self._previous = {s: signal.signal(s, self._on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
        return self

    def __exit__(self, *exc: object) -> None:
        for s, handler in self._previous.items():
            signal.signal(s, handler)  # type: ignore[arg-type]
