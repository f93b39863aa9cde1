"""Where lostx finds the models and data that live beside the project (no network at run time)."""

from __future__ import annotations

import os
from pathlib import Path


def shared_dir() -> Path:
    """``$LOSTX_SHARED``, else ``../shared`` from the working directory, else beside the source checkout."""
    env = os.environ.get("LOSTX_SHARED")
    if env:
        return Path(env)
    candidates = (Path.cwd() / ".." / "shared", Path(__file__).resolve().parents[1] / ".." / "shared")
    for candidate in candidates:
        if candidate.is_dir():
            return candidate.resolve()
    return candidates[0]


def models_dir() -> Path:
    """Model files: ``$LOSTX_MODELS``, else ``<shared>/models``."""
    env = os.environ.get("LOSTX_MODELS")
    return Path(env) if env else shared_dir() / "models"


def data_dir() -> Path:
    """Sample datasets: ``$LOSTX_DATA``, else ``<shared>/data``."""
    env = os.environ.get("LOSTX_DATA")
    return Path(env) if env else shared_dir() / "data"


def cache_dir() -> Path:
    """Where commands keep what they can rebuild (the demo's map): ``$XDG_CACHE_HOME/lostx``."""
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "lostx"
