"""SKYLOC_OT_camera_preset: make the scene camera one of the NavCam presets (pinhole)."""
from __future__ import annotations

import bpy  # noqa: TID251 (extension layer)

from .. import bridge


class SKYLOC_OT_camera_preset(bpy.types.Operator):
    """Give the rover camera the chosen NavCam's image size and field of view, and its mast height"""

    bl_idname = "skyloc.camera_preset"
    bl_label = "Apply camera preset"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        from blender_addon.core.cameras import get_preset
        from blender_addon.scene import set_perspective

        s = bridge.settings(context)
        try:
            preset = get_preset(s.camera)
            cam = context.scene.camera or bpy.data.objects.get("SkylocCamera")
            if cam is None:
                raise ValueError("no camera: press 'Place rover' first")
            set_perspective(cam, preset.camera_model(), scene=context.scene)
            s.mast_height_m = preset.mast_height_m
        except Exception as exc:  # noqa: BLE001 (reported to the user)
            return bridge.fail(self, "Camera preset", exc)
        s.status = f"camera {preset.name}: {preset.width} x {preset.height} px, {preset.hfov_deg:g} deg"
        self.report({"INFO"}, s.status)
        return {"FINISHED"}
