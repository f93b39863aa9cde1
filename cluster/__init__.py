"""lostx.cluster: the work that spreads over machines. Building a map's frames on a Ray cluster
(``lostx map build --ray``); Ray itself is imported only when a build uses it (``pip install "lostx[ray]"``)."""

from lostx.core.lazy import lazy_exports

_EXPORTS = {"RayDescribers": ".raybuild"}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
