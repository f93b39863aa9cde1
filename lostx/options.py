"""Command-line options shared by several commands, and turning them into a :class:`Config`."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from lostx.core.config import Config, load_config


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
    group.add_argument("--window", type=int, help="frames in the sequence filter's window (default 20)")
    group.add_argument("--no-tracker", action="store_true", help="answer without the route tracker")


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
    sequence, tracker = config.sequence, config.tracker
    if getattr(args, "window", None):
        sequence = dataclasses.replace(sequence, length=args.window)
    if getattr(args, "no_tracker", False):
        tracker = dataclasses.replace(tracker, enabled=False)
    return dataclasses.replace(config, backbone=backbone, verify=verify, sequence=sequence, tracker=tracker)
