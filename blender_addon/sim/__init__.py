"""The simulator's Blender side (imports bpy through :mod:`blender_addon.scene`): it drives the scene.

* :class:`Simulator` (:mod:`.simulator`) keeps one site's terrain built in Blender and renders
  acquisitions near it;
* :func:`generate_dataset` (:mod:`.dataset`) renders the test sets of a scene file with it.

What to simulate and what gets written (poses, jobs, plans, scene files, manifests) is bpy-free and
lives in :mod:`blender_addon.core`; this package only turns it into Blender renders.
"""
from blender_addon.sim.dataset import generate_dataset
from blender_addon.sim.simulator import Simulator

__all__ = ["Simulator", "generate_dataset"]
