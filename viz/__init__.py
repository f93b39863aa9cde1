"""lostx.viz: the live Rerun view of the localizer.

``RerunSink(refmap, ViewerOutput(rrd=...))`` is a sink ``sink(frame, estimate)``
with ``close()``; ``lostx.options`` builds one from command-line options.
Importing this package does not import Rerun; importing :mod:`lostx.viz.sink` does.
"""

import os

# Rerun's SDK writes an error line for every batch it cannot send to a viewer that went away (over a hundred for a
# viewer closed during one run); the live view says so itself, once, when it hands the rest over. Set before Rerun
# loads, which reads it once; a RUST_LOG of the user's own is kept.
os.environ.setdefault("RUST_LOG", "warn,re_grpc_client=off,re_sdk::recording_stream=off")

from .target import DEFAULT_CONNECT, DEFAULT_MEMORY_LIMIT, DEFAULT_WEB_ADDRESS, ViewerOutput  # noqa: E402

__all__ = ["DEFAULT_CONNECT", "DEFAULT_MEMORY_LIMIT", "DEFAULT_WEB_ADDRESS", "ViewerOutput"]
