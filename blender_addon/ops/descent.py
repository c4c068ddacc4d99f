"""SKYLOC_OT_descent_*: the descent panel's operators (build the scene, place the lander, render a pair).

They read ``Scene.skyloc_descent`` (:mod:`blender_addon.ui_descent`), call the bpy-free simulator
(:mod:`blender_addon.descent`) and the Blender path (:mod:`blender_addon.scene.descent`).
"""
from __future__ import annotations

import logging
from pathlib import Path

import bpy  # noqa: TID251 (extension layer)

from board.errors import SkylocError

log = logging.getLogger(__name__)


def _config(s):
    """The DescentConfig of the panel's settings (eq. 9, the panel's thermal model)."""
    from blender_addon.descent.lights import default_lights
    from blender_addon.descent.render import AppearanceOptions
    from blender_addon.descent.simulate import DescentConfig

    return DescentConfig(terrain=f"procedural:europa:{s.terrain_seed}", trajectory=s.trajectory, trial=s.trial,
                         appearance=AppearanceOptions(thermal=s.thermal_model),
                         lights=tuple(default_lights(sun_azimuth_deg=s.sun_azimuth_deg,
                                                     sun_elevation_deg=s.sun_elevation_deg)),
                         width=s.width, height=s.height, terrain_res_m=s.terrain_res_m,
                         terrain_size_m=s.terrain_size_m)


def _renderer(cfg):
    from blender_addon.descent.simulate import cached_renderer

    return cached_renderer(cfg.terrain, cfg.terrain_res_m, cfg.terrain_size_m, tuple(cfg.lights), cfg.appearance)


def _pose(cfg, renderer, t_s: float):
    from blender_addon.descent.simulate import trial_motion

    m = trial_motion(cfg, renderer.terrain)
    return m, m.rotation([t_s])[0], m.position([t_s])[0]


def _fail(op, what: str, exc: Exception) -> set[str]:
    log.error("%s failed", what, exc_info=True)
    op.report({"ERROR"}, f"{what} failed: {exc}")
    return {"CANCELLED"}


class SKYLOC_OT_descent_build(bpy.types.Operator):
    """Build the procedural Europa terrain of the descent (heights, eq. 9 and temperature materials)"""

    bl_idname = "skyloc.descent_build"
    bl_label = "Build descent terrain"
    bl_options = {"REGISTER"}

    def execute(self, context):
        from blender_addon.scene.descent import build_descent_scene

        s = context.scene.skyloc_descent
        try:
            r = _renderer(_config(s))
            build_descent_scene(r, reset=False)
        except SkylocError as exc:
            return _fail(self, "Build descent terrain", exc)
        s.status = f"terrain {r.terrain.spec}: {r.terrain.shape[1]} x {r.terrain.shape[0]} nodes"
        self.report({"INFO"}, s.status)
        return {"FINISHED"}


class SKYLOC_OT_descent_place(bpy.types.Operator):
    """Place the lander on its trajectory at the panel's time and show the whole trajectory"""

    bl_idname = "skyloc.descent_place"
    bl_label = "Place lander / preview trajectory"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        import numpy as np

        from blender_addon.scene.descent import place_descent_camera, show_trajectory

        s = context.scene.skyloc_descent
        try:
            cfg = _config(s)
            r = _renderer(cfg)
            m, R, p = _pose(cfg, r, s.time_s)
            if bpy.data.objects.get("SkylocDescentCamera") is None:
                raise SkylocError("build the descent terrain first (Build descent terrain)")
            place_descent_camera(cfg.cameras()["visible"], R, p)
            show_trajectory(m.position(np.linspace(0.0, cfg.duration_s, 201)))
        except SkylocError as exc:
            return _fail(self, "Place lander", exc)
        s.status = f"lander at ({p[0]:.1f}, {p[1]:.1f}, {p[2]:.1f}) m, t = {s.time_s:.0f} s"
        self.report({"INFO"}, s.status)
        return {"FINISHED"}


class SKYLOC_OT_descent_render_pair(bpy.types.Operator):
    """Render the visible/thermal frame pair at the lander's pose with Cycles (eq. 9 nodes, temperature texture)"""

    bl_idname = "skyloc.descent_render_pair"
    bl_label = "Render frame pair"
    bl_options = {"REGISTER"}

    def execute(self, context):
        import cv2
        import numpy as np

        from blender_addon.scene.descent import render_pair

        s = context.scene.skyloc_descent
        try:
            cfg = _config(s)
            r = _renderer(cfg)
            _, R, p = _pose(cfg, r, s.time_s)
            pair = render_pair(cfg.cameras()["visible"], R, p)
            out = Path(bpy.path.abspath(s.out_dir or "//skyloc_descent")).resolve()
            out.mkdir(parents=True, exist_ok=True)
            rng = np.random.default_rng(0)
            stem = f"traj{cfg.trajectory:02d}_trial{cfg.trial:02d}_t{s.time_s:06.1f}"
            cv2.imwrite(str(out / f"{stem}_visible.png"), cfg.visible_sensor.counts(pair["visible"], rng))
            cv2.imwrite(str(out / f"{stem}_thermal.png"), cfg.thermal_sensor.counts(pair["thermal"], rng))
        except (SkylocError, OSError) as exc:
            return _fail(self, "Render frame pair", exc)
        s.status = f"wrote {out / stem}_visible.png and _thermal.png (K = 0.01 x count)"
        self.report({"INFO"}, s.status)
        return {"FINISHED"}


classes = (SKYLOC_OT_descent_build, SKYLOC_OT_descent_place, SKYLOC_OT_descent_render_pair)

#: register in order, unregister in reverse (Blender's own helper)
register, unregister = bpy.utils.register_classes_factory(classes)
