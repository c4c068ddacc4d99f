"""Pose estimation from skyline matches: exact rotation on the sphere, sub-grid refinement, confidence."""
