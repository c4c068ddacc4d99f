"""SKYLOC_OT_place_rover: the camera at the rover pose (site, mast height, heading/pitch/roll)."""
from __future__ import annotations

import bpy  # noqa: TID251 (extension layer)

from .. import bridge


class SKYLOC_OT_place_rover(bpy.types.Operator):
    """Put the rover camera at the site, mast height above the ground, with heading, pitch and roll"""

    bl_idname = "skyloc.place_rover"
    bl_label = "Place rover"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        from blender_addon.core.terrain_mesh import sample_height
        from blender_addon.scene import place_camera

        s = bridge.settings(context)
        try:
            terrain = bridge.require_terrain()
            p = bridge.pose(s)
            z = sample_height(terrain, p.x, p.y) + float(s.mast_height_m)
            place_camera(p.x, p.y, z, p.heading_deg, p.pitch_deg, p.roll_deg, scene=context.scene)
        except Exception as exc:  # noqa: BLE001 (reported to the user)
            return bridge.fail(self, "Place rover", exc)
        s.status = f"rover at ({p.x:.1f}, {p.y:.1f}) m, eye z {z:.2f} m"
        self.report({"INFO"}, s.status)
        return {"FINISHED"}
