"""``lostx backbones``: the registered semantic backbones and where their models are looked for."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("backbones", help="list the semantic backbones and their default model files")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from lostx.core.backbones import default_model_paths

    for name, path in default_model_paths().items():
        print(f"{name:24s} {path} ({'found' if path.is_file() else 'missing'})")
    return 0
