"""The "Skyloc" tab of the 3D View sidebar (N panel): one panel per step of the workflow."""
from __future__ import annotations

import bpy  # noqa: TID251 (extension layer)

from .ops import (
    SKYLOC_OT_acquire,
    SKYLOC_OT_build_terrain,
    SKYLOC_OT_camera_preset,
    SKYLOC_OT_import_dem,
    SKYLOC_OT_place_rover,
    SKYLOC_OT_render_database,
    SKYLOC_OT_render_panorama,
)


class _SkylocPanel:
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Skyloc"

    @classmethod
    def poll(cls, context):
        return getattr(context.scene, "skyloc", None) is not None


class SKYLOC_PT_terrain(_SkylocPanel, bpy.types.Panel):
    bl_label = "DEM and terrain"
    bl_idname = "SKYLOC_PT_terrain"

    def draw(self, context):
        s = context.scene.skyloc
        col = self.layout.column(align=True)
        col.prop(s, "dem")
        col.prop(s, "body")
        col.operator(SKYLOC_OT_import_dem.bl_idname, icon="IMPORT")
        col.separator()
        row = col.row(align=True)
        row.prop(s, "site_x")
        row.prop(s, "site_y")
        col.prop(s, "grid_half_m")
        col.prop(s, "max_radius_m")
        col.operator(SKYLOC_OT_build_terrain.bl_idname, icon="MESH_GRID")


class SKYLOC_PT_rover(_SkylocPanel, bpy.types.Panel):
    bl_label = "Rover and camera"
    bl_idname = "SKYLOC_PT_rover"

    def draw(self, context):
        s = context.scene.skyloc
        col = self.layout.column(align=True)
        col.prop(s, "heading_deg")
        col.prop(s, "pitch_deg")
        col.prop(s, "roll_deg")
        col.prop(s, "mast_height_m")
        col.operator(SKYLOC_OT_place_rover.bl_idname, icon="OUTLINER_OB_CAMERA")
        col.separator()
        col.prop(s, "camera")
        col.operator(SKYLOC_OT_camera_preset.bl_idname, icon="CAMERA_DATA")


class SKYLOC_PT_products(_SkylocPanel, bpy.types.Panel):
    bl_label = "Acquisitions and panoramas"
    bl_idname = "SKYLOC_PT_products"

    def draw(self, context):
        s = context.scene.skyloc
        col = self.layout.column(align=True)
        col.prop(s, "preset")
        col.prop(s, "seed")
        col.prop(s, "out_dir")
        row = col.row(align=True)
        row.prop(s, "frames")
        row.prop(s, "arc_deg")
        col.prop(s, "frame_width")
        col.operator(SKYLOC_OT_acquire.bl_idname, icon="RENDER_STILL")
        col.prop(s, "pano_width")
        col.prop(s, "pano_band_deg")
        col.operator(SKYLOC_OT_render_panorama.bl_idname, icon="WORLD")


class SKYLOC_PT_database(_SkylocPanel, bpy.types.Panel):
    bl_label = "Skyline database"
    bl_idname = "SKYLOC_PT_database"

    def draw(self, context):
        s = context.scene.skyloc
        col = self.layout.column(align=True)
        row = col.row(align=True)
        row.prop(s, "db_size_m")
        row.prop(s, "db_step_m")
        col.prop(s, "renderer")
        col.prop(s, "use_service")
        if s.use_service:
            col.prop(s, "service_url")
            col.prop(s, "service_token")
        col.operator(SKYLOC_OT_render_database.bl_idname, icon="NETWORK_DRIVE")


class SKYLOC_PT_status(_SkylocPanel, bpy.types.Panel):
    bl_label = "Progress"
    bl_idname = "SKYLOC_PT_status"

    def draw(self, context):
        s = context.scene.skyloc
        if hasattr(self.layout, "progress"):
            self.layout.progress(factor=s.progress, type="BAR", text=s.status or "idle")
        else:  # Blender < 4.0
            self.layout.prop(s, "progress", text=s.status or "idle", slider=True)


classes = (SKYLOC_PT_terrain, SKYLOC_PT_rover, SKYLOC_PT_products, SKYLOC_PT_database, SKYLOC_PT_status)


def register() -> None:
    for cls in classes:
        bpy.utils.register_class(cls)


def unregister() -> None:
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
