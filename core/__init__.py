"""lostx.core: the method. Pure computation: no sockets, no viewer, no CLI parsing.

The main entry points::

    from lostx.core import Config, ReferenceMap, Localizer, build_map, load_backbone
"""

from .backbones import Backbone, BackboneInfo, SemanticFrame, backbone_names, load_backbone, register_backbone
from .build import BuildSummary, build_map
from .config import Config, load_config
from .describe import LostDescriber
from .errors import ImageError, InputError, LostxError, MapError, ModelError
from .estimate import Candidate, Estimate, Evidence
from .frame import Frame
from .localizer import Localizer
from .matcher import MatchResult, PlaceMatcher
from .refmap import ReferenceMap
from .thumbnail import ThumbnailDescriber

__all__ = [
    "Backbone", "BackboneInfo", "BuildSummary", "Candidate", "Config", "Estimate", "Evidence", "Frame",
    "ImageError", "InputError", "Localizer", "LostDescriber", "LostxError", "MapError", "MatchResult",
    "ModelError", "PlaceMatcher", "ReferenceMap", "SemanticFrame", "ThumbnailDescriber", "backbone_names",
    "build_map", "load_backbone", "load_config", "register_backbone",
]
