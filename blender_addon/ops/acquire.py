"""SKYLOC_OT_acquire: a simulated NavCam acquisition (pan-tilt frames + manifest) at the rover pose."""
from __future__ import annotations

import bpy  # noqa: TID251 (extension layer)

from .. import bridge


def _simulator(Simulator, s):
    """A Simulator on the terrain already built in this scene (by the Build terrain operator).

    Simulator() resets the Blender session (read_factory_settings), which must not happen inside
    an operator (it frees the operator's own context and crashes Blender); ``Simulator.adopt``
    takes over the built terrain instead.
    """
    return Simulator.adopt(bridge.require_terrain(), dem_spec=s.dem.strip(), dem_path=bridge.SESSION.dem_path,
                           grid_half_m=float(s.grid_half_m))


class SKYLOC_OT_acquire(bpy.types.Operator):
    """Render the pan-tilt frames of the chosen camera at the rover pose into an acquisition folder"""

    bl_idname = "skyloc.acquire"
    bl_label = "Acquire"
    bl_options = {"REGISTER"}

    def execute(self, context):
        from blender_addon.core.acquire import AcquisitionJob
        from blender_addon.core.cameras import get_preset
        from blender_addon.core.degrade import check_look_body, get_degradation
        from blender_addon.core.plans import plan_frames
        from blender_addon.sim import Simulator

        s = bridge.settings(context)
        try:
            with bridge.Progress(context, "acquire") as prog:
                preset = get_preset(s.camera, width=int(s.frame_width) or None)
                sim = _simulator(Simulator, s)
                job = AcquisitionJob(bridge.pose(s), preset,
                                     plan_frames(int(s.frames), float(s.arc_deg), preset.hfov_deg),
                                     get_degradation(s.preset), seed=int(s.seed))
                look = check_look_body(job.degradation, sim.terrain.body.name)
                if look:
                    self.report({"WARNING"}, look)
                out = bridge.out_dir(s) / "acquisition"
                sim.acquire(job, out, progress=lambda i, n, msg: prog.update(i / max(n, 1), msg))
        except Exception as exc:  # noqa: BLE001 (reported to the user)
            return bridge.fail(self, "Acquire", exc)
        s.status = f"acquisition written to {out}"  # after the progress context, which ends with "done"
        self.report({"INFO"}, s.status)
        return {"FINISHED"}
