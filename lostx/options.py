"""Command-line options shared by several commands, and turning them into a :class:`Config`."""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from lostx.core.config import Config, load_config

if TYPE_CHECKING:
    from lostx.core.refmap import ReferenceMap
    from lostx.viz.sink import RerunSink


def add_backbone_options(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("backbone")
    group.add_argument("--backbone", help="semantic backbone name (see `lostx backbones`)")
    group.add_argument("--model", type=Path, help="model file of the backbone (default: in ../shared/models)")
    group.add_argument("--device", help="cpu, cuda or cuda:N (PyTorch backbones)")
    group.add_argument("--threads", type=int, help="CPU threads for the network")


def add_config_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", type=Path, help="TOML file of settings (see docs/config.md)")
    add_backbone_options(parser)
    group = parser.add_argument_group("matching")
    group.add_argument("--scoring", choices=["eq4-lost", "eq4", "released"], help="verification score")
    group.add_argument("--top-k", type=int, help="candidates verified per query (default 10)")


def config_from_args(args: argparse.Namespace) -> Config:
    config = load_config(getattr(args, "config", None))
    backbone = config.backbone
    for field, option in (("name", "backbone"), ("model_path", "model"), ("device", "device"), ("threads", "threads")):
        value = getattr(args, option, None)
        if value is not None:
            backbone = dataclasses.replace(backbone, **{field: value})
    verify = config.verify
    if getattr(args, "scoring", None):
        verify = dataclasses.replace(verify, scoring=args.scoring)
    if getattr(args, "top_k", None):
        verify = dataclasses.replace(verify, top_k=args.top_k)
    return dataclasses.replace(config, backbone=backbone, verify=verify)


def add_viewer_options(parser: argparse.ArgumentParser) -> None:
    """The live view's options: where the Rerun recording goes, and how much of it."""
    from lostx.viz.target import DEFAULT_CONNECT, DEFAULT_MEMORY_LIMIT

    group = parser.add_argument_group("live view (Rerun; see docs/viewer.md)")
    group.add_argument("--viewer", action="store_true", help="spawn the Rerun viewer and stream to it")
    group.add_argument("--connect", nargs="?", const=DEFAULT_CONNECT, metavar="URL",
                       help=f"stream to a running Rerun viewer (default URL {DEFAULT_CONNECT})")
    group.add_argument("--rrd", type=Path, metavar="FILE", help="record to an .rrd file (open it with `rerun FILE`)")
    group.add_argument("--web", action="store_true", help="serve the web viewer and print its URL")
    group.add_argument("--viewer-rate", type=float, default=10.0, metavar="HZ",
                       help="most frames per second whose images, label maps and lines are logged "
                            "(the rest of the view is logged every frame; 0: every frame; default 10)")
    group.add_argument("--viewer-memory", default=DEFAULT_MEMORY_LIMIT, metavar="LIMIT",
                       help=f"memory limit of the spawned viewer and the web server's buffer, e.g. 4GiB or 25%% "
                            f"(oldest data dropped first; default {DEFAULT_MEMORY_LIMIT})")


def viewer_sink_from_args(args: argparse.Namespace, refmap: ReferenceMap) -> RerunSink | None:
    """A Rerun sink for the destinations the options name, or None where they name none."""
    from lostx.viz.target import DEFAULT_MEMORY_LIMIT, ViewerOutput

    output = ViewerOutput(
        spawn=bool(getattr(args, "viewer", False)),
        connect=getattr(args, "connect", None),
        rrd=getattr(args, "rrd", None),
        web=bool(getattr(args, "web", False)),
        memory_limit=getattr(args, "viewer_memory", None) or DEFAULT_MEMORY_LIMIT,
    )
    if not output.any:
        return None
    from lostx.viz.sink import RerunSink, SinkSettings  # imports Rerun: only when a view is asked for

    rate = getattr(args, "viewer_rate", None)
    sink = RerunSink(refmap, output, SinkSettings(heavy_hz=rate if rate and rate > 0 else None))
    for message in sink.opened.messages:
        print(f"lostx: {message}", file=sys.stderr)
    return sink


def close_viewer(sink: RerunSink | None) -> None:
    """Finish a sink from :func:`viewer_sink_from_args`; with ``--web``, keep serving until Ctrl-C first."""
    if sink is None:
        return
    if sink.opened.web_url is not None:
        sink.flush()
        print(f"lostx: serving the web viewer at {sink.opened.web_url}; press Ctrl-C to stop", file=sys.stderr)
        try:
            while True:
                time.sleep(3600)
        except KeyboardInterrupt:
            pass
    sink.close()
