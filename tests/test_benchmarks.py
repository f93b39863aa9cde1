"""Every benchmark and study runs in its ``--quick`` form, so that a change to the library that breaks one fails
here rather than the next time someone measures. Each runs as a person runs it (its own process, from
benchmarks/, on the shared data); it must print its table and write a JSON that holds measured figures."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any, Iterator

import pytest

from lostx.core.paths import data_dir, models_dir, shared_dir

BENCHMARKS = Path(__file__).resolve().parent.parent / "benchmarks"
SCRIPTS = sorted([*BENCHMARKS.glob("bench_*.py"), *BENCHMARKS.glob("study_*.py")])
TIMEOUT_S = 180
NEEDS = {"bench_raybuild.py": "ray", "bench_ros2.py": "cyclonedds"}
"""Scripts that need an optional package of the test extra: skipped, saying which, where it is not installed."""
NOT_MEASURED = {"machine", "load_average"}
"""What describes the machine the run was on rather than what it measured."""


def numbers(value: Any) -> Iterator[float]:
    """Every number in a JSON value, however deep."""
    if isinstance(value, dict):
        for item in value.values():
            yield from numbers(item)
    elif isinstance(value, list):
        for item in value:
            yield from numbers(item)
    elif isinstance(value, (int, float)) and not isinstance(value, bool):
        yield float(value)


def run_quick(script: Path, out: Path) -> subprocess.CompletedProcess:
    """``script --quick --out out``. On a timeout its whole process group is killed: the benchmarks start services,
    Ray and DDS peers that must not outlive the test."""
    env = {**os.environ, "LOSTX_SHARED": str(shared_dir())}
    proc = subprocess.Popen([sys.executable, script.name, "--quick", "--out", str(out)], cwd=BENCHMARKS, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        stdout, stderr = proc.communicate(timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        stdout, stderr = proc.communicate()
        pytest.fail(f"{script.name} --quick ran over {TIMEOUT_S} s\n{stdout[-2000:]}\n{stderr[-4000:]}")
    return subprocess.CompletedProcess(proc.args, proc.returncode, stdout, stderr)


def test_scripts_are_found() -> None:
    names = {script.name for script in SCRIPTS}
    assert {"bench_localizer.py", "study_heading.py"} <= names and not names & {"common.py", "scenes.py"}
    assert set(NEEDS) <= names


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda script: script.stem)
def test_quick_run(script: Path, tmp_path: Path) -> None:
    if script.name in NEEDS:
        pytest.importorskip(NEEDS[script.name], reason=f"{script.name} needs {NEEDS[script.name]} (the test extra)")
    for needed in (data_dir(), models_dir()):
        if not needed.is_dir():
            pytest.fail(f"test data missing: {needed} (set LOSTX_SHARED to the folder holding data/ and models/)")
    out = tmp_path / f"{script.stem}.json"
    proc = run_quick(script, out)
    assert proc.returncode == 0, f"{script.name} --quick failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-4000:]}"
    printed = proc.stdout.splitlines()
    assert f"wrote {out}" in printed, proc.stdout
    assert len([line for line in printed[:printed.index(f"wrote {out}")] if line.strip()]) >= 3, proc.stdout

    payload = json.loads(out.read_text())
    tables = {key: value for key, value in payload.items()
              if key not in NOT_MEASURED and isinstance(value, (dict, list))}
    assert tables and all(tables.values()), f"{script.name}: an empty table in {out}: {payload}"
    figures = [x for x in numbers(tables) if math.isfinite(x) and x > 0]
    assert figures, f"{script.name}: no measured figure in {out}: {payload}"


def _figures(by_scene: dict[str, tuple[int, int, int, int]]) -> dict:
    """A variant's results as the studies hold them: S1 and S2, single and sequence, right answers, at 2 Hz."""
    from scenes import Counts

    return {scene: {"2 Hz": {"S1": {"single": Counts(right=a), "sequence": Counts(right=b)},
                             "S2": {"single": Counts(right=c), "sequence": Counts(right=d)}}}
            for scene, (a, b, c, d) in by_scene.items()}


@pytest.fixture()
def scenes_module():
    sys.path.insert(0, str(BENCHMARKS))
    try:
        import scenes
        yield scenes
    finally:
        sys.path.remove(str(BENCHMARKS))


def test_a_choice_that_wins_one_scene_by_a_query_and_loses_the_other_does_not_carry(scenes_module) -> None:
    """The sequence straight in frames against following the distance, as measured on the two nuScenes scenes: chosen
    on scene-0523 (113 against 112) it loses scene-0916 13 (39 against 52), so the family does not carry; the rule
    keeps the default."""
    results = {"straight in frames": _figures({"scene-0523": (31, 31, 23, 28), "scene-0916": (9, 12, 7, 11)}),
               "following the distance (default)": _figures({"scene-0523": (30, 28, 24, 30),
                                                              "scene-0916": (12, 15, 10, 15)})}
    assert scenes_module.chosen_on(results, "scene-0523") == "straight in frames"
    assert scenes_module.chosen_on(results, "scene-0916") == "following the distance (default)"
    assert not scenes_module.carries(results)
    assert scenes_module.rule(results) == "following the distance (default)"


def test_a_choice_within_noise_on_both_scenes_carries(scenes_module) -> None:
    """The distance window, 30, 45 or 60 m, as measured: each scene's choice is within two queries of the other
    scene's best."""
    results = {"30 m": _figures({"scene-0523": (30, 28, 24, 30), "scene-0916": (12, 15, 11, 16)}),
               "45 m (default)": _figures({"scene-0523": (30, 28, 24, 30), "scene-0916": (12, 15, 10, 15)}),
               "60 m": _figures({"scene-0523": (30, 28, 25, 30), "scene-0916": (12, 15, 11, 15)})}
    assert scenes_module.chosen_on(results, "scene-0523") == "60 m"
    assert scenes_module.chosen_on(results, "scene-0916") == "30 m"
    assert scenes_module.carries(results)
    worse = {**results, "60 m": _figures({"scene-0523": (30, 28, 25, 30), "scene-0916": (11, 14, 10, 14)})}
    assert not scenes_module.carries(worse)  # 60 m chosen on scene-0523 now falls 4 short of scene-0916's best
