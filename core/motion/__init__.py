"""How the camera moved between frames: poses on the road plane, from a source's odometry or, where it has
none, from the frames themselves (monocular visual odometry, made metric by the camera's height).

- :mod:`.pose`: planar poses (x, y, yaw) and their algebra; the camera's ground frame from the vehicle's pose;
- :mod:`.visual`: visual odometry between consecutive frames of one camera;
- :mod:`.odometer`: a stream's running pose and distance travelled, from whichever source it has.

May import: the foundations (geometry, config, frame, errors).
"""
