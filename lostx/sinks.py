"""Naming sinks on the command line: ``lostx serve --sink NAME[=ARG]``.

NAME is one of :data:`SINKS` or an import path ``package.module:factory``; the
factory is called with ARG (a string) when one is given, else with nothing,
and returns a sink (``sink(frame, estimate)``, optionally ``close()``). The
table holds import paths as strings so that naming a sink imports only that
sink's code: the Rerun viewer is not loaded unless asked for.
"""

from __future__ import annotations

import importlib
from typing import Any

from lostx.core.errors import InputError

SINKS: dict[str, str] = {
    "jsonl": "lostx.stream.sinks:JsonlSink",  # --sink jsonl=PATH: every estimate's summary as a JSON line
    # Other packages register theirs here, e.g. the Rerun viewer from lostx.viz.
}


def resolve_sink(spec: str) -> Any:
    name, has_arg, arg = spec.partition("=")
    target = SINKS.get(name, name)
    module_name, colon, attr = target.partition(":")
    if not colon or not module_name or not attr:
        known = ", ".join(sorted(SINKS))
        raise InputError(f"unknown sink {name!r}: use one of {known}, or package.module:factory[=ARG]")
    try:
        factory = getattr(importlib.import_module(module_name), attr)
    except (ImportError, AttributeError) as exc:
        raise InputError(f"sink {name!r}: cannot load {target} ({exc})") from None
    try:
        sink = factory(arg) if has_arg else factory()
    except TypeError as exc:
        raise InputError(f"sink {name!r}: {exc}") from None
    if not callable(sink):
        raise InputError(f"sink {name!r}: {target} did not return a callable sink(frame, estimate)")
    return sink
