"""Describing a frame: what the network's output is turned into before any map is consulted.

Holds the LoST descriptor (Eq. 1-3), the semantic keypoints, the class groups and their coverage check,
the describer that runs a backbone and computes all of them for a frame, the thumbnail baseline, the
fitting of a camera's frames to a common geometry, and the profile of what frames look like.

May import: :mod:`lostx.core.backbones` and the foundations (config, errors, frame, images).
"""
