"""lostx.core: the method. Pure computation: no sockets, no viewer, no CLI parsing.

A frame's way through it, one package per stage, each importing only the stages below it::

    backbones/   the network: deep features and class probabilities
    describe/    LoST descriptor, keypoints, class groups, thumbnails, camera fitting
    maps/        reference maps: format, reader, writer, index
    match/       candidate search, verification, scores, the sequence filter's costs
    route/       sequence filter, route tracker, heading filter
    decide/      confidence calibrated on the map, the Estimate
    localizer.py the stages in order, one frame in, one Estimate out
    build.py     a map from a traverse

config, errors, frame, images, outputs and paths are the foundations every stage may use.

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
    "LostDescriber": ".describe.describer",
    **dict.fromkeys(("ImageError", "InputError", "LostxError", "MapError", "ModelError"), ".errors"),
    **dict.fromkeys(("Candidate", "Estimate", "Evidence"), ".decide.estimate"),
    "Frame": ".frame",
    "Localizer": ".localizer",
    **dict.fromkeys(("MatchResult", "PlaceMatcher"), ".match.matcher"),
    "ReferenceMap": ".maps.refmap",
    "ThumbnailDescriber": ".describe.thumbnail",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
