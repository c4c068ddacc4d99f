"""Point the scene camera like a NavCam on a pan-tilt unit (bpy layer).

The body attitude (heading, pitch, roll) and the curved-scene levelling come from
:func:`blender_addon.scene.camera.camera_world_matrix`; the pan and tilt of the unit are
composed with :func:`board.camera.rotation_body_from_camera`, the same composition the
board uses to read the frames back, so the manifest's angles describe the render exactly.
"""
from __future__ import annotations

import logging

import bpy  # noqa: TID251 (scene building is the bpy layer)
import numpy as np
from mathutils import Matrix

from blender_addon.scene.camera import BODY_FROM_BLENDER_CAM, CAMERA_NAME, camera_world_matrix, place_camera
from board.camera import rotation_body_from_camera

log = logging.getLogger(__name__)

#: OpenCV camera axes (x right, y down, z forward) -> Blender camera axes (x right, y up, z backward).
CV_TO_BLENDER_CAM = np.diag([1.0, -1.0, -1.0])


def pan_tilt_matrix(x: float, y: float, z: float, heading_deg: float, pitch_deg: float, roll_deg: float,
                    pan_deg: float, tilt_deg: float, *, scene: bpy.types.Scene | None = None) -> np.ndarray:
    """4x4 scene matrix of the Blender camera of a frame taken at ``pan``/``tilt`` (degrees).

    x, y : world position (projected CRS, metres); z : optical centre height (metres, DEM datum).
    """
    m = camera_world_matrix(x, y, z, heading_deg, pitch_deg, roll_deg, scene=scene)
    scene_from_body = m[:3, :3] @ BODY_FROM_BLENDER_CAM.T
    out = m.copy()
    out[:3, :3] = scene_from_body @ rotation_body_from_camera(pan_deg, tilt_deg) @ CV_TO_BLENDER_CAM
    return out


def point_camera(x: float, y: float, z: float, heading_deg: float, pitch_deg: float, roll_deg: float,
                 pan_deg: float, tilt_deg: float, *, scene: bpy.types.Scene | None = None,
                 name: str = CAMERA_NAME) -> bpy.types.Object:
    """Place the scene camera for one frame of an acquisition and return it."""
    obj = place_camera(x, y, z, heading_deg, pitch_deg, roll_deg, scene=scene, name=name)
    obj.matrix_world = Matrix(pan_tilt_matrix(x, y, z, heading_deg, pitch_deg, roll_deg, pan_deg, tilt_deg,
                                              scene=scene).tolist())
    obj["skyloc_pan_tilt"] = [pan_deg, tilt_deg]
    return obj
