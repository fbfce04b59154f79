"""Pose of parts from camera images, tracking and camera calibration (no I/O of its own).

model.py: image convention, part template, detections; edges.py: subpixel
edges and fits; locate.py: every part in one image; tracking.py: identities
across frames; calibration.py: pixel size and the camera-to-plate transform.
"""
