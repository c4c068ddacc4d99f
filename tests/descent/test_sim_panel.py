"""The add-on's descent panel: registers, builds the scene, places the lander on its trajectory, renders a pair."""
import sys

import cv2
import numpy as np
import pytest


def test_descent_core_never_imports_bpy():
    import subprocess

    code = ("import sys, blender_addon.descent.simulate, blender_addon.descent.thermal, blender_addon.descent.sensors\n"
            "print('bpy' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "False"


@pytest.mark.blender
@pytest.mark.slow
def test_panel_operators_run_end_to_end(tmp_path):
    bpy = pytest.importorskip("bpy")
    import blender_addon
    from blender_addon.descent.simulate import trial_motion
    from blender_addon.ops.descent import _config, _renderer

    bpy.ops.wm.read_factory_settings(use_empty=True)
    blender_addon.register()
    try:
        assert hasattr(bpy.types, "SKYLOC_PT_descent") and hasattr(bpy.types.Scene, "skyloc_descent")
        s = bpy.context.scene.skyloc_descent
        s.terrain_size_m, s.terrain_res_m, s.trajectory, s.time_s = 200.0, 1.0, 9, 50.0
        s.width, s.height, s.out_dir = 48, 36, str(tmp_path)
        # placing before building is refused with the fix
        with pytest.raises(RuntimeError, match="build the descent terrain first"):
            bpy.ops.skyloc.descent_place()
        assert bpy.ops.skyloc.descent_build() == {"FINISHED"}
        assert bpy.ops.skyloc.descent_place() == {"FINISHED"}
        cfg = _config(s)
        motion = trial_motion(cfg, _renderer(cfg).terrain)
        cam = bpy.data.objects["SkylocDescentCamera"]
        expected = motion.position([50.0])[0] + motion.rotation([50.0])[0] @ cfg.cameras()["visible"].t_body_cam
        np.testing.assert_allclose(np.array(cam.matrix_world.translation), expected, atol=1e-4)
        assert len(bpy.data.objects["SkylocDescentTrajectory"].data.splines[0].points) == 201
        assert bpy.ops.skyloc.descent_render_pair() == {"FINISHED"}
        vis = cv2.imread(str(tmp_path / "traj09_trial00_t0050.0_visible.png"), cv2.IMREAD_UNCHANGED)
        th = cv2.imread(str(tmp_path / "traj09_trial00_t0050.0_thermal.png"), cv2.IMREAD_UNCHANGED)
        assert vis.shape == th.shape == (36, 48) and th.dtype == np.uint16
        # the Cycles pair equals the fast renderer's at the same pose (to the mesh's triangulation)
        fast = _renderer(cfg).render(cfg.cameras()["thermal"], motion.rotation([50.0])[0], motion.position([50.0])[0])
        assert np.isfinite(fast["thermal"]).all()
        assert np.median(np.abs(th * 0.01 - fast["thermal"])) < 0.05
    finally:
        blender_addon.unregister()
    assert not hasattr(bpy.types.Scene, "skyloc_descent")
