"""Matching one frame against a map: candidate search, keypoint verification (Eq. 4), the scores of any
map frame, the sequence filter's cost sources, and the index's recall check.

May import: :mod:`lostx.core.maps`, :mod:`lostx.core.describe`, :mod:`lostx.core.backbones` and the
foundations; not :mod:`lostx.core.route`, which follows the route without knowing how frames are matched.
"""
