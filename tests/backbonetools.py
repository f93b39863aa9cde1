"""Helpers for the backbone tests: the ``lostx`` command run in this process (fast) or in a child process
(where the environment must differ: the Python path, packages that are not installed), and its answers."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from lostx.core.backbones.mosaic import ADE20K_CLASSES
from lostx.core.paths import models_dir

MOSAIC = models_dir() / "mosaic-r4-ade20k31-uint8.tflite"


@dataclass
class Ran:
    code: int
    out: str
    err: str

    def error_line(self, *fragments: str) -> str:
        """The one ``lostx: error:`` line of a failed run (no traceback), checked to hold ``fragments``."""
        assert self.code != 0 and "Traceback" not in self.err, self.err
        lines = [line for line in self.err.splitlines() if line.strip()]
        assert len(lines) == 1 and lines[0].startswith("lostx: error: "), self.err
        for fragment in fragments:
            assert fragment in lines[0], lines[0]
        return lines[0]


def lostx(capsys: pytest.CaptureFixture, *args: object) -> Ran:
    """``lostx ARGS`` in this process."""
    from lostx.cli import main

    capsys.readouterr()
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return Ran(code, out, err)


BLOCK = """
import importlib.abc, sys
class NotInstalled(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
sys.meta_path.insert(0, NotInstalled())
"""


def lostx_child(*args: object, pythonpath: Path | None = None, blocked: tuple[str, ...] = ()) -> Ran:
    """``lostx ARGS`` in a child process with ``pythonpath`` first on its path and the ``blocked`` packages
    unimportable (as if not installed)."""
    env = dict(os.environ)
    if pythonpath is not None:
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(pythonpath), env.get("PYTHONPATH")]))
    code = f"BLOCKED = {set(blocked)!r}\n{BLOCK}\nfrom lostx.cli import main\nsys.exit(main(sys.argv[1:]))"
    proc = subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True, text=True, env=env,
                          timeout=600)
    return Ran(proc.returncode, proc.stdout, proc.stderr)


def answers(path: Path) -> list[tuple[int, str]]:
    """Each query's match and candidates, from a ``lostx match`` CSV."""
    return [(int(row["match_index"]), row["candidates"]) for row in csv.DictReader(path.open())]


def toml_value(value: object) -> str:
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {toml_value(v)}" for k, v in value.items()) + " }"
    return json.dumps(value)


def describe_mosaic(folder: Path, **changes: object) -> Path:
    """The shared MOSAIC file linked (never copied) into ``folder`` as ``mosaic.tflite``, with a TOML description
    beside it as a user writes it, ``changes`` applied (None drops a key); returns the model path."""
    keys: dict[str, object] = {
        "model": "mosaic.tflite",
        "features": "MobilenetV3/Conv_1/Relu",
        "scores": "decoder/add",
        "classes": list(ADE20K_CLASSES),
        "default_classes": "street",
        "resize": "area",
        **changes,
    }
    folder.mkdir(parents=True, exist_ok=True)
    model = folder / "mosaic.tflite"
    if not model.exists():
        model.symlink_to(MOSAIC)
    model.with_suffix(".toml").write_text(
        "".join(f"{key} = {toml_value(value)}\n" for key, value in keys.items() if value is not None))
    return model
