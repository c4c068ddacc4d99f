"""SKYLOC_OT_import_dem: check a DEM (or synthesise the procedural one) and centre the site on it."""
from __future__ import annotations

import bpy  # noqa: TID251 (extension layer)

from .. import bridge


class SKYLOC_OT_import_dem(bpy.types.Operator):
    """Read the DEM's description (size, cell, CRS, body); put the site at its centre if outside it"""

    bl_idname = "skyloc.import_dem"
    bl_label = "Import DEM"
    bl_options = {"REGISTER"}

    def execute(self, context):
        from blender_addon.terrain.dem import dem_info

        s = bridge.settings(context)
        try:
            with bridge.Progress(context, "import DEM") as prog:
                path = bridge.dem_path(s)
                bridge.SESSION.dem_path = path
                info = dem_info(path, body=bridge.body_arg(s))
                xmin, ymin, xmax, ymax = info.bounds
                if not (xmin < s.site_x < xmax and ymin < s.site_y < ymax):
                    s.site_x, s.site_y = (xmin + xmax) / 2.0, (ymin + ymax) / 2.0
                prog.update(1.0, f"{path.name}: {info.size[0]} x {info.size[1]} cells at {info.cell_m:g} m, "
                                 f"body {info.body.name}")
        except Exception as exc:  # noqa: BLE001 (reported to the user)
            return bridge.fail(self, "Import DEM", exc)
        self.report({"INFO"}, s.status)
        return {"FINISHED"}
