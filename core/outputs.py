"""Checking, before any work, that an output can be written where it is asked for; and, once written, making a
folder's entries durable.

A command that describes thousands of frames and only then finds that its
``--out`` is a folder, or that nothing can be written there, has wasted the
work; these checks run first. They create nothing.
"""

from __future__ import annotations

import os
from pathlib import Path

from .errors import InputError


def check_output_file(path: str | Path, what: str) -> Path:
    """``path`` can be (re)written as a file; ``what`` names it in the error (e.g. ``--out``)."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{what} {path} is a folder; give the name of a file to write")
    if path.exists() and not os.access(path, os.W_OK):
        raise InputError(f"{what} {path} cannot be written ({_why_not(path)})")
    _check_parent(path, what)
    return path


def check_output_folder(path: str | Path, what: str) -> Path:
    """``path`` is a folder that can be written into, or one that can be created."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InputError(f"{what} {path} is a file, not a folder")
    if path.is_dir():
        if not os.access(path, os.W_OK | os.X_OK):
            raise InputError(f"{what} {path} cannot be written into ({_why_not(path)})")
        return path
    _check_parent(path, what)
    return path


def _check_parent(path: Path, what: str) -> None:
    """The nearest existing folder above ``path`` is a folder that can be written into."""
    parent = path.absolute().parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise InputError(f"{what} {path}: {parent} is a file, not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"{what} {path}: cannot write in {parent} ({_why_not(parent)})")


def _why_not(path: Path) -> str:
    """Why a path that exists cannot be written: its file system is mounted read-only, or permissions."""
    return "a read-only file system" if os.statvfs(path).f_flag & os.ST_RDONLY else "no permission"


def sync_folder(folder: Path) -> None:
    """Make a folder's entries (files created, renamed, removed) survive a crash of the machine."""
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
