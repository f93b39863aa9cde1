"""The README's Python example runs as written, on the sample data beside the clone."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

from lostx.core.paths import shared_dir

README = Path(__file__).resolve().parents[1] / "README.md"


def test_the_python_example_runs_as_written(tmp_path):
    block = next(b for b in re.findall(r"```python\n(.*?)```", README.read_text(), re.S) if "build_map(" in b)
    clone = tmp_path / "lostx"  # the README's layout: the clone and shared/ side by side
    clone.mkdir()
    (tmp_path / "shared").symlink_to(shared_dir(), target_is_directory=True)
    proc = subprocess.run([sys.executable, "-P", "-c", block], cwd=clone, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    rows = [line.split() for line in proc.stdout.splitlines()]
    assert len(rows) == 10
    # name, match, state, confidence per night frame; the k-th night frame shows day frame k.
    assert all(abs(int(row[1]) - k) <= 1 for k, row in enumerate(rows)), proc.stdout  # measured: all within one
    states = [" ".join(row[2:-1]) for row in rows]
    assert states[:2] == ["warming up", "warming up"]  # the 3-frame window fills on the third frame
    # Ten map frames leave too few wrong answers to measure: the localizer never claims to be sure here.
    assert states[2:] == ["not_localized"] * 8
    assert (clone / "day.map" / "manifest.json").is_file()


def test_every_environment_variable_a_user_sets_is_in_the_readme():
    root = README.parent
    sources = [p for folder in ("core", "lostx", "stream", "replay", "viz", "evaluation", "cluster")
               for p in (root / folder).rglob("*.py")]
    read = {name for p in sources for name in re.findall(r"os\.environ\.get\(\"(LOSTX_[A-Z_]+)\"", p.read_text())}
    assert {"LOSTX_SHARED", "LOSTX_MODELS", "LOSTX_DATA"} <= read
    text = README.read_text()
    assert [name for name in sorted(read) if f"`${name}`" not in text] == []
