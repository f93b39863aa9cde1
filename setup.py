"""The design's top-level folders install as one package, ``lostx``: each folder is a subpackage
(``core/`` is ``lostx.core``), and every package below them is found, not listed.
Everything else about the project is in pyproject.toml."""

from setuptools import find_packages, setup

FOLDERS = {"lostx": "lostx", "lostx.core": "core", "lostx.stream": "stream", "lostx.replay": "replay",
           "lostx.viz": "viz", "lostx.evaluation": "evaluation", "lostx.cluster": "cluster"}

packages = [f"{name}.{sub}" for name, folder in FOLDERS.items() for sub in find_packages(folder)]
setup(package_dir=FOLDERS, packages=[*FOLDERS, *packages])
