"""The Blender path (eq. 9 as shader nodes, temperature as an emission texture) against the fast renderer."""
import numpy as np
import pytest

from blender_addon.descent.lights import default_lights
from blender_addon.descent.render import AppearanceOptions, DescentRenderer
from blender_addon.descent.simulate import default_camera
from blender_addon.descent.terrain import procedural_europa
from board.conventions import rotation_enu_from_camera


@pytest.mark.blender
@pytest.mark.slow
@pytest.mark.parametrize("shadows", [False, True])
def test_blender_path_agrees_with_the_fast_renderer(shadows):
    pytest.importorskip("bpy")
    from blender_addon.scene import descent as blender_descent

    terrain = procedural_europa(5, size_m=120.0, res_m=0.5)
    r = DescentRenderer(terrain, default_lights(sun_elevation_deg=20.0), AppearanceOptions(shadows=shadows))
    cam = default_camera(96, 72, 50.0)
    R = rotation_enu_from_camera(30.0, 3.0, -2.0)
    p = np.array([5.0, -4.0, 70.0])
    f = r.render(cam, R, p)
    # with shadows, also build only the frame's footprint (+ 2 m) instead of the whole terrain
    window = (np.nanmin(f["x"]) - 2, np.nanmin(f["y"]) - 2, np.nanmax(f["x"]) + 2, np.nanmax(f["y"]) + 2)
    blender_descent.build_descent_scene(r, window=window if shadows else None)
    b = blender_descent.render_pair(cam, R, p)
    assert b["visible"].shape == f["visible"].shape == (72, 96)
    for key, median_tol, p90_tol in (("visible", 2e-3, 2e-2), ("thermal", 0.05, 0.5)):
        d = np.abs(b[key] - f[key])
        # the mesh's triangles differ from the bilinear surface by millimetres: tiny median, edges of blocks in p90
        assert np.median(d) < median_tol and np.percentile(d, 90) < p90_tol, (key, np.median(d), np.percentile(d, 90))
    # and the agreement is not trivial: the images have structure
    assert np.std(f["visible"]) > 0.02 and np.ptp(f["thermal"]) > 10.0


@pytest.mark.blender
def test_blender_path_refuses_hapke():
    pytest.importorskip("bpy")
    from blender_addon.scene import descent as blender_descent
    from board.errors import InvalidInputError

    r = DescentRenderer(procedural_europa(5, size_m=40.0, res_m=1.0), default_lights(),
                        AppearanceOptions(brdf="hapke"))
    with pytest.raises(InvalidInputError, match="eq. 9 only"):
        blender_descent.build_descent_scene(r)
