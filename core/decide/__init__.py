"""The answer and how sure it is: the confidence calibrated on the map's own wrong answers, and the
:class:`Estimate` every frame gets.

May import: :mod:`lostx.core.match` (an estimate carries its correspondences) and the foundations.
"""
