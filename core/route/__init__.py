"""Following the route over frames: the online sequence filter, the route tracker (Kalman filter) and the
heading filter (discrete Bayes). Pure filters over numbers handed in.

May import: the foundations (config, frame) only.
"""
