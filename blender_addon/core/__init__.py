"""bpy-free simulator logic: terrain meshes, camera presets, plans, degradations, datasets."""
