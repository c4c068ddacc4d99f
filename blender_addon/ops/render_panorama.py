"""SKYLOC_OT_render_panorama: an equirectangular panorama folder at the rover pose."""
from __future__ import annotations

import bpy  # noqa: TID251 (extension layer)

from .. import bridge


class SKYLOC_OT_render_panorama(bpy.types.Operator):
    """Render a 360-degree panorama (binary or dressed look) at the rover pose into a panorama folder"""

    bl_idname = "skyloc.render_panorama"
    bl_label = "Render panorama"
    bl_options = {"REGISTER"}

    def execute(self, context):
        from blender_addon.scene.panorama import make_panorama

        s = bridge.settings(context)
        try:
            with bridge.Progress(context, "panorama") as prog:
                terrain = bridge.require_terrain()
                binary = s.preset == "binary"
                out = make_panorama(terrain, bridge.pose(s), bridge.out_dir(s) / "panorama",
                                    height_m=float(s.mast_height_m), width=int(s.pano_width) // 2 * 2, binary=binary,
                                    preset=None if binary else s.preset, seed=int(s.seed), dem=s.dem, build=False,
                                    elevation_range_deg=tuple(float(v) for v in s.pano_band_deg))
                prog.update(1.0, "panorama written")
        except Exception as exc:  # noqa: BLE001 (reported to the user)
            return bridge.fail(self, "Render panorama", exc)
        s.status = f"panorama written to {out}"  # after the progress context, which ends with "done"
        self.report({"INFO"}, s.status)
        return {"FINISHED"}
