"""Shared fixtures: the real model and the real images in ../shared (never copied into the repo)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lostx.core.paths import data_dir, models_dir

ROBOTCAR = data_dir() / "robotcar-daynight"
NORDLAND = data_dir() / "nordland-64x32"


def _require(path: Path) -> Path:
    if not path.exists():
        pytest.fail(f"test data missing: {path} (set LOSTX_SHARED to the folder holding data/ and models/)")
    return path


@pytest.fixture(scope="session")
def robotcar() -> Path:
    return _require(ROBOTCAR)


@pytest.fixture(scope="session")
def nordland() -> Path:
    return _require(NORDLAND)


@pytest.fixture(scope="session")
def mosaic():
    """The default backbone, loaded once per test session."""
    from lostx.core.backbones import load_backbone

    _require(models_dir())
    return load_backbone()


@pytest.fixture(scope="session")
def day_map(tmp_path_factory, robotcar, mosaic):
    """A LoST map of the ten RobotCar day frames, built with the default settings."""
    from lostx.core.build import build_map
    from lostx.core.describe.describer import LostDescriber
    from lostx.core.maps.refmap import ReferenceMap
    from lostx.replay.folder import folder_traverse

    out = tmp_path_factory.mktemp("maps") / "day"
    traverse = folder_traverse(robotcar / "day")
    build_map(traverse, out, describer=LostDescriber(mosaic), metadata={"image_root": str(robotcar / "day")},
              progress=False)
    return ReferenceMap.open(out)


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(1234)
