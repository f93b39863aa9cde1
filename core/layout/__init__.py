"""The layout of a place seen from one calibrated camera: where the road, the other ground, and the
buildings, vegetation, vehicles and other things standing on it are, on a bird's-eye grid around the
stretch of road the camera looks at. It survives a 180-degree turn where appearance does not: the same
stretch seen from its other end has the same layout, turned (SPOT's principle, with one camera).

- :mod:`.classes`: which of the model's classes are road, other ground, sky, and what stands on the ground;
- :mod:`.projection`: every label pixel's ray onto the road plane (a table per camera), a frame's labels
  turned into ground points and the points where things touch the ground;
- :mod:`.grid`: a window of frames' points brought into one camera's ground frame with the motion between
  them, binned on the grid, and the grids stored in a map;
- :mod:`.compare`: grids compared as they are and turned 180 degrees (a masked correlation per channel);
- :mod:`.curve`: where the camera viewing a map frame's stretch from its other end stands, by the map's route
  (on a bend the two views are not 180 degrees apart);
- :mod:`.describer`: the running window of a stream, and the centred windows of a map (each also gathered as
  its stretch's other end sees it).

May import: :mod:`lostx.core.motion`, :mod:`lostx.core.backbones` and the foundations.
"""
