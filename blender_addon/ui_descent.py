"""The "Descent" panel of the Skyloc sidebar tab: place a lander, preview a trajectory, render a frame pair.

Settings live in ``Scene.skyloc_descent`` (SKYLOC_PG_descent); the operators are in
:mod:`blender_addon.ops.descent`.
"""
from __future__ import annotations

import bpy  # noqa: TID251 (extension layer)
from bpy.props import EnumProperty, FloatProperty, IntProperty, PointerProperty, StringProperty

from .ops.descent import SKYLOC_OT_descent_build, SKYLOC_OT_descent_place, SKYLOC_OT_descent_render_pair


class SKYLOC_PG_descent(bpy.types.PropertyGroup):
    terrain_seed: IntProperty(name="Terrain seed", default=1, min=0, description="procedural:europa:SEED")
    terrain_size_m: FloatProperty(name="Size (m)", default=400.0, min=20.0, max=4000.0)
    terrain_res_m: FloatProperty(name="Cell (m)", default=0.5, min=0.05, max=10.0,
                                 description="Node spacing of the terrain (0.25 m in the campaign; 0.5 m is "
                                             "lighter in the viewport)")
    trajectory: IntProperty(name="Trajectory", default=3, min=1, max=10)
    trial: IntProperty(name="Trial", default=0, min=0)
    time_s: FloatProperty(name="Time (s)", default=0.0, min=0.0, max=200.0)
    thermal_model: EnumProperty(name="Thermal", items=[("tm", "Memorandum", "instantaneous balance + smoothing"),
                                                       ("conduction", "Conduction", "1-D conduction over the day")])
    sun_azimuth_deg: FloatProperty(name="Sun azimuth", default=90.0, min=0.0, max=360.0)
    sun_elevation_deg: FloatProperty(name="Sun elevation", default=30.0, min=0.5, max=90.0)
    width: IntProperty(name="Width", default=640, min=8, max=4096)
    height: IntProperty(name="Height", default=480, min=8, max=4096)
    out_dir: StringProperty(name="Output", default="//skyloc_descent", subtype="DIR_PATH")
    status: StringProperty(name="Status", default="")


class SKYLOC_PT_descent(bpy.types.Panel):
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Skyloc"
    bl_label = "Descent (icy moon)"
    bl_idname = "SKYLOC_PT_descent"

    @classmethod
    def poll(cls, context):
        return getattr(context.scene, "skyloc_descent", None) is not None

    def draw(self, context):
        s = context.scene.skyloc_descent
        col = self.layout.column(align=True)
        col.prop(s, "terrain_seed")
        row = col.row(align=True)
        row.prop(s, "terrain_size_m")
        row.prop(s, "terrain_res_m")
        col.prop(s, "thermal_model")
        row = col.row(align=True)
        row.prop(s, "sun_azimuth_deg")
        row.prop(s, "sun_elevation_deg")
        col.operator(SKYLOC_OT_descent_build.bl_idname, icon="MESH_GRID")
        col.separator()
        row = col.row(align=True)
        row.prop(s, "trajectory")
        row.prop(s, "trial")
        col.prop(s, "time_s")
        col.operator(SKYLOC_OT_descent_place.bl_idname, icon="OUTLINER_OB_CAMERA")
        col.separator()
        row = col.row(align=True)
        row.prop(s, "width")
        row.prop(s, "height")
        col.prop(s, "out_dir")
        col.operator(SKYLOC_OT_descent_render_pair.bl_idname, icon="RENDER_STILL")
        if s.status:
            col.label(text=s.status)


classes = (SKYLOC_PG_descent, SKYLOC_PT_descent)


def register() -> None:
    from .ops import descent as ops_descent

    ops_descent.register()
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.Scene.skyloc_descent = PointerProperty(type=SKYLOC_PG_descent)


def unregister() -> None:
    from .ops import descent as ops_descent

    del bpy.types.Scene.skyloc_descent
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
    ops_descent.unregister()
