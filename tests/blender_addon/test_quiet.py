"""Blender's native "Saved: '...png'" lines stay off stdout (file descriptor 1), renders still land.

capfd captures at the descriptor level, where Blender's C code writes, so these tests see exactly
what a terminal or a pipe would see.
"""
from __future__ import annotations

import logging
import os

import numpy as np
import pytest

pytest.importorskip("bpy")

from blender_addon import scene as S  # noqa: E402
from blender_addon.scene.quiet import native_stdout_captured  # noqa: E402
from blender_addon.terrain.model import MultiResTerrain, TerrainLevel  # noqa: E402
from board.conventions import BODIES  # noqa: E402

pytestmark = pytest.mark.blender


def _plain() -> MultiResTerrain:
    """A flat 20 m x 20 m plain at height 0 (1 m cells) centred on the origin."""
    return MultiResTerrain([TerrainLevel(np.zeros((20, 20), np.float32), -10.0, 10.0, 1.0)], "",
                           BODIES["mars"], (0.0, 0.0))


def test_render_prints_no_saved_line_and_still_writes_the_image(tmp_path, capfd, caplog):
    S.reset_scene()
    S.build_terrain(_plain(), refine=False)
    S.place_camera(0.0, 0.0, 1.5, 0.0, 0.0, 0.0)
    S.configure_binary()
    capfd.readouterr()                                   # drop what scene building printed
    print("before render", flush=True)
    os.write(1, b"native before\n")
    with caplog.at_level(logging.DEBUG, logger="blender_addon.scene.quiet"):
        path = S.render_equirect(tmp_path / "p.png", width=32, height=16)
    print("after render", flush=True)
    os.write(1, b"native after\n")
    out, _ = capfd.readouterr()
    assert "Saved:" not in out
    # stdout works again, in order, on both the Python and the descriptor level
    assert out.splitlines() == ["before render", "native before", "after render", "native after"]
    # what Blender said went to the debug log instead
    assert any("Saved:" in r.getMessage() for r in caplog.records)
    # the render itself: the plain (white) below the camera, black sky above
    assert path == tmp_path / "p.png" and path.is_file()
    assert not list(tmp_path.glob(".*"))                 # no temporary render left behind
    img = S.read_image(path)
    assert img.shape == (16, 32)
    assert (img[0] == 0.0).all() and (img[-1] == 1.0).all()


def test_redirection_is_undone_when_the_block_raises(capfd):
    capfd.readouterr()
    with pytest.raises(ZeroDivisionError):
        with native_stdout_captured() as said:
            os.write(1, b"swallowed\n")
            1 / 0
    os.write(1, b"visible\n")
    out, _ = capfd.readouterr()
    assert out == "visible\n"
    assert said.text == "swallowed\n"
