"""The house's rules: every module is packaged, the layers point down and nothing imports in a circle.

import-linter reads the package as it installs (a wheel built from this checkout, unpacked), so that it
sees every module of every top-level folder; the contracts are in pyproject.toml.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
FOLDERS = {"lostx": "lostx", "core": "lostx/core", "stream": "lostx/stream", "replay": "lostx/replay",
           "viz": "lostx/viz", "evaluation": "lostx/evaluation", "cluster": "lostx/cluster"}
LINT_IMPORTS = Path(sys.executable).with_name("lint-imports")


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """The package as a wheel installs it: a folder holding ``lostx/`` with every subpackage in place."""
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "-w", str(out),
                    str(ROOT)], check=True, capture_output=True)
    site = out / "site"
    with zipfile.ZipFile(next(out.glob("lostx-*.whl"))) as wheel:
        wheel.extractall(site)
    return site


def source_modules() -> set[str]:
    """Every module of the design's folders, as the path it installs at."""
    return {f"{target}/{path.relative_to(ROOT / folder).as_posix()}"
            for folder, target in FOLDERS.items() for path in (ROOT / folder).rglob("*.py")
            if "__pycache__" not in path.parts}


def lint_imports(site: Path) -> subprocess.CompletedProcess:
    # Run from the unpacked wheel: lint-imports puts its working folder first on the path.
    return subprocess.run([str(LINT_IMPORTS), str(ROOT / "pyproject.toml"), "--no-cache"], cwd=site,
                          capture_output=True, text=True)


def test_every_module_of_every_folder_is_packaged(installed):
    packaged = {p.relative_to(installed).as_posix() for p in (installed / "lostx").rglob("*.py")}
    assert source_modules() - packaged == set()
    assert len(packaged) >= 120


def test_the_layers_point_down_and_nothing_imports_in_a_circle(installed):
    run = lint_imports(installed)
    assert run.returncode == 0, run.stdout + run.stderr
    analysed = int(re.search(r"Analyzed (\d+) files", run.stdout).group(1))
    assert analysed == len(source_modules())  # every module, not only the top folder's
    assert "3 kept, 0 broken" in run.stdout


def test_a_stage_importing_a_later_one_breaks_the_contracts(installed, tmp_path):
    site = tmp_path / "site"
    shutil.copytree(installed, site)
    lost = site / "lostx/core/describe/lost.py"
    lost.write_text(lost.read_text() + "\nfrom lostx.core.localizer import Localizer  # noqa: E402\n")
    run = lint_imports(site)
    assert run.returncode != 0
    assert "lostx.core.describe is not allowed to import lostx.core.localizer" in run.stdout
    assert "No cycles are allowed in lostx.core." in run.stdout


def test_the_core_importing_the_command_line_breaks_the_contracts(installed, tmp_path):
    site = tmp_path / "site"
    shutil.copytree(installed, site)
    frame = site / "lostx/core/frame.py"
    frame.write_text(frame.read_text() + "\nimport lostx.viz.sink  # noqa: E402\n")
    run = lint_imports(site)
    assert run.returncode != 0
    assert "lostx.core is not allowed to import lostx.viz" in run.stdout
