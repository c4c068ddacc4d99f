"""skyloc on-board segment: panoramas, skyline detection, matching, pose and confidence.

Imports nothing else of skyloc (numpy, OpenCV and zarr only).
"""
__version__ = "0.1.0"
