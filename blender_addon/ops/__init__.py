"""Operators of the Skyloc extension, one SKYLOC_OT_* per module."""
from __future__ import annotations

import bpy  # noqa: TID251 (extension layer)

from .acquire import SKYLOC_OT_acquire
from .build_terrain import SKYLOC_OT_build_terrain
from .camera_preset import SKYLOC_OT_camera_preset
from .import_dem import SKYLOC_OT_import_dem
from .place_rover import SKYLOC_OT_place_rover
from .render_database import SKYLOC_OT_render_database
from .render_panorama import SKYLOC_OT_render_panorama

classes = (
    SKYLOC_OT_import_dem,
    SKYLOC_OT_build_terrain,
    SKYLOC_OT_place_rover,
    SKYLOC_OT_camera_preset,
    SKYLOC_OT_acquire,
    SKYLOC_OT_render_panorama,
    SKYLOC_OT_render_database,
)

#: register in order, unregister in reverse (Blender's own helper)
register, unregister = bpy.utils.register_classes_factory(classes)
