"""Reference maps: their format on disk, reading one memory-mapped, writing and checkpointing a build,
and the approximate index of its descriptors.

May import: :mod:`lostx.core.describe`, :mod:`lostx.core.backbones` and the foundations.
"""
