"""Perception: ArUco marker localisation (markers.py) and the pose estimator (ekf.py)."""
