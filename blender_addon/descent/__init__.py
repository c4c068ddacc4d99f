"""Icy-moon descent simulator (bpy-free): Europa terrain at lander scale, visible and thermal appearance,
sensors (cameras, IMU, altimeter), the ten trajectories and the fast ray-casting renderer.

The simulator writes descent sequences (:mod:`board.descent.sequence`); ``simulate.simulate_trial``
is the one entry point the CLI, the Dask campaign and the Blender panel call.  Frames and units are
those of the sequence contract: world x east, y north, z up (m), body x forward, y left, z up,
OpenCV camera frames, time in seconds.  See docs/descent.md.
"""
