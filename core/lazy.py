"""Package attributes imported on first use (PEP 562), so that importing a package costs nothing
until one of its names is used: ``lostx --help`` starts without numpy, OpenCV or ZeroMQ."""

from __future__ import annotations

import importlib
from typing import Any, Callable


def lazy_exports(package: str, exports: dict[str, str]) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """``__getattr__`` and ``__dir__`` for ``package`` whose public ``name`` lives in module ``exports[name]``
    (relative to the package, e.g. ``".localizer"``)."""

    def getattr_(name: str) -> Any:
        module = exports.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module, package), name)
        setattr(importlib.import_module(package), name, value)  # the next look-up is a plain attribute
        return value

    def dir_() -> list[str]:
        return sorted({*vars(importlib.import_module(package)), *exports})

    return getattr_, dir_
