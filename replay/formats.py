"""The names of the traverse and pair formats (a module of its own: the command line lists them
without loading the readers)."""

from typing import Literal

Format = Literal["folder", "robotcar", "bag", "video", "nuscenes", "vprbench", "pairs"]
FORMATS: tuple[str, ...] = ("folder", "robotcar", "bag", "video", "nuscenes", "vprbench", "pairs")
