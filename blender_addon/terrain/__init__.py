"""bpy-free terrain: DEM import (GDAL), procedural terrain, multi-resolution levels."""
