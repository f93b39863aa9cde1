"""lostx.core: the method. Pure computation: no sockets, no viewer, no CLI parsing.

The main entry points::

    from lostx.core import Config, ReferenceMap, Localizer, build_map, load_backbone

Names are imported on first use, so importing a submodule (``lostx.core.config``)
does not load the network or the localizer.
"""

from .lazy import lazy_exports

_EXPORTS = {
    **dict.fromkeys(("Backbone", "BackboneInfo", "SemanticFrame", "backbone_names", "load_backbone",
                      "register_backbone"), ".backbones"),
    **dict.fromkeys(("BuildSummary", "build_map"), ".build"),
    **dict.fromkeys(("Config", "load_config"), ".config"),
    "LostDescriber": ".describe",
    **dict.fromkeys(("ImageError", "InputError", "LostxError", "MapError", "ModelError"), ".errors"),
    **dict.fromkeys(("Candidate", "Estimate", "Evidence"), ".estimate"),
    "Frame": ".frame",
    "Localizer": ".localizer",
    **dict.fromkeys(("MatchResult", "PlaceMatcher"), ".matcher"),
    "ReferenceMap": ".refmap",
    "ThumbnailDescriber": ".thumbnail",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
