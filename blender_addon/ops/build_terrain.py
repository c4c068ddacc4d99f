"""SKYLOC_OT_build_terrain: the multi-resolution terrain around the site, as meshes."""
from __future__ import annotations

import bpy  # noqa: TID251 (extension layer)

from .. import bridge


class SKYLOC_OT_build_terrain(bpy.types.Operator):
    """Build the multi-resolution terrain around the site (fine near it, coarser rings outward)"""

    bl_idname = "skyloc.build_terrain"
    bl_label = "Build terrain"
    bl_options = {"REGISTER"}

    def execute(self, context):
        from blender_addon.scene import build_terrain
        from blender_addon.terrain.multires import build_multires

        s = bridge.settings(context)
        try:
            with bridge.Progress(context, "build terrain") as prog:
                path = bridge.dem_path(s)
                terrain = build_multires(path, bridge.site_xy(s), grid_half_m=float(s.grid_half_m),
                                         max_radius_m=float(s.max_radius_m) or None, body=bridge.body_arg(s))
                prog.update(0.3, f"{len(terrain.levels)} levels read")
                build_terrain(terrain, scene=context.scene,
                              progress=lambda f, msg: prog.update(0.3 + 0.7 * f, msg))
                bridge.SESSION.terrain, bridge.SESSION.dem_path = terrain, path
        except Exception as exc:  # noqa: BLE001 (reported to the user)
            return bridge.fail(self, "Build terrain", exc)
        self.report({"INFO"}, f"terrain built: {len(terrain.levels)} levels")
        return {"FINISHED"}
