"""Errors a user can act on.

Every error raised on bad input is a :class:`LostxError`; its message names the
file, field or value at fault and, where there is one, the way out. The CLI
prints the message on one line and exits non-zero without a traceback.
"""

from __future__ import annotations


class LostxError(Exception):
    """Base class for every error lostx raises on bad input or bad state."""


class ModelError(LostxError):
    """A model file is missing, truncated, or not the model it claims to be."""


class ImageError(LostxError):
    """An image cannot be read, or is not an H x W x 3 uint8 frame."""


class MapError(LostxError):
    """A reference map is missing, incomplete, corrupt, or from another backbone."""


class InputError(LostxError):
    """A folder, CSV, frame or argument that cannot be used as given."""


class StateError(LostxError):
    """A localizer's state that cannot be saved or restored (a part that does not carry, or a saved state
    from other settings)."""
