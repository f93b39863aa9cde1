"""lostx.viz: the live Rerun view of the localizer.

``RerunSink(refmap, ViewerOutput(rrd=...))`` is a sink ``sink(frame, estimate)``
with ``close()``; ``lostx.options`` builds one from command-line options.
Importing this package does not import Rerun; importing :mod:`lostx.viz.sink` does.
"""

from .target import DEFAULT_CONNECT, DEFAULT_MEMORY_LIMIT, DEFAULT_WEB_ADDRESS, ViewerOutput

__all__ = ["DEFAULT_CONNECT", "DEFAULT_MEMORY_LIMIT", "DEFAULT_WEB_ADDRESS", "ViewerOutput"]
