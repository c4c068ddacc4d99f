"""Skyline detection in azimuth/elevation images.

``detect_skyline`` (sky-region consistency, confidence masking) is the detector skyloc uses;
``detect_baseline`` reproduces the reference report's graph method for comparison.
"""
from board.detect.baseline import detect_baseline
from board.detect.sky_regions import Detection, DetectorParams, detect_skyline

__all__ = ["Detection", "DetectorParams", "detect_baseline", "detect_skyline"]
