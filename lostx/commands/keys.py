"""``lostx keys DIR --name NAME``: make a CurveZMQ key pair for the service or one of its clients."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("keys", help="make a CurveZMQ key pair (for a service exposed on a network)")
    parser.add_argument("directory", type=Path, help="folder to write NAME.key and NAME.key_secret into")
    parser.add_argument("--name", default="server", help="key name (default: server)")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from lostx.core.outputs import check_output_folder
    from lostx.stream.sockets import make_keys

    check_output_folder(args.directory, "DIRECTORY")
    public, secret = make_keys(args.directory, args.name)
    print(f"public key {public} (give it to the other side)\nsecret key {secret} (keep it; mode 0600)")
    print("service: lostx serve --curve-secret server.key_secret --curve-clients DIR_OF_CLIENT_.key_FILES\n"
          "clients: --curve-server server.key --curve-secret NAME.key_secret")
    return 0
