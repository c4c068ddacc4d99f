"""Cameras at ENU poses: world position (projected CRS, metres) plus heading, pitch, roll.

The rover body frame is board.conventions' (x forward, y left, z up); a Blender camera looks
along its local -Z with +Y up and +X right, so the camera axes in the body frame are
``x_cam = -y_body``, ``y_cam = z_body``, ``z_cam = -x_body``.  The same holds for Cycles'
equirectangular panorama camera: the image centre looks along the heading and the top row is
the body's zenith.

On a curved scene (see :mod:`blender_addon.core.terrain_mesh`) the camera is also tilted to the
scene's local normal at its position, so "level" means level on the body's sphere.
"""
from __future__ import annotations

import logging
import math

import bpy  # noqa: TID251 (scene building is the bpy layer)
import numpy as np
from mathutils import Matrix

from blender_addon.core.terrain_mesh import local_up_enu, scene_z
from blender_addon.scene import state
from board.camera import CameraModel
from board.conventions import rotation_enu_from_camera

log = logging.getLogger(__name__)

CAMERA_NAME = "SkylocCamera"

#: columns: Blender camera axes (x right, y up, z backward) expressed in the body frame
BODY_FROM_BLENDER_CAM = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def _tilt_to(up: np.ndarray) -> np.ndarray:
    """Smallest rotation taking (0, 0, 1) to the unit vector ``up``."""
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, up)
    s = np.linalg.norm(axis)
    if s < 1e-15:
        return np.eye(3)
    axis /= s
    ang = math.atan2(s, float(np.dot(z, up)))
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(ang) * k + (1 - math.cos(ang)) * (k @ k)


def camera_world_matrix(x: float, y: float, z: float, heading_deg: float, pitch_deg: float = 0.0,
                        roll_deg: float = 0.0, *, scene: bpy.types.Scene | None = None) -> np.ndarray:
    """4x4 scene matrix of a Blender camera at world (x, y, z) metres with that attitude."""
    off = state.get_offset(scene)
    radius, k = state.get_curvature(scene)
    rot = _tilt_to(local_up_enu(x, y, off, radius, k)) @ rotation_enu_from_camera(heading_deg, pitch_deg, roll_deg)
    m = np.eye(4)
    m[:3, :3] = rot @ BODY_FROM_BLENDER_CAM
    m[:3, 3] = (x - off.x_m, y - off.y_m, float(scene_z(z, x, y, off, radius, k)))
    return m


def place_camera(x: float, y: float, z: float, heading_deg: float, pitch_deg: float = 0.0, roll_deg: float = 0.0,
                 *, scene: bpy.types.Scene | None = None, name: str = CAMERA_NAME) -> bpy.types.Object:
    """Create (or move) the camera ``name`` to world (x, y, z) metres, heading/pitch/roll degrees.

    x, y : projected CRS, metres; z : height of the optical centre (same datum as the DEM), metres.
    The camera becomes the scene camera.  Only its matrix changes when it already exists, so a
    persistent render session keeps its BVH.
    """
    scene = state.get_scene(scene)
    obj = bpy.data.objects.get(name)
    if obj is None:
        cam = bpy.data.cameras.new(name)
        cam.clip_start = 0.05
        cam.clip_end = 1.0e7
        obj = bpy.data.objects.new(name, cam)
        scene.collection.objects.link(obj)
    obj.matrix_world = Matrix(camera_world_matrix(x, y, z, heading_deg, pitch_deg, roll_deg, scene=scene).tolist())
    obj["skyloc_pose"] = [x, y, z, heading_deg, pitch_deg, roll_deg]
    if scene.camera != obj:          # assigning, even the same camera, forces a full Cycles resync
        scene.camera = obj
    return obj


def set_equirect(cam_obj: bpy.types.Object, *, lat_range_deg: tuple[float, float] = (-90.0, 90.0),
                 lon_range_deg: tuple[float, float] = (-180.0, 180.0)) -> None:
    """Make the camera an equirectangular panorama over the given ranges (degrees, camera frame).

    Longitude and latitude are Blender's (longitude 0 = the view axis).  Use
    :func:`blender_addon.scene.render.render_equirect`, which takes azimuth/elevation ranges.
    """
    cam = cam_obj.data
    cam.type = "PANO"
    cam.panorama_type = "EQUIRECTANGULAR"
    cam.latitude_min, cam.latitude_max = (math.radians(v) for v in lat_range_deg)
    cam.longitude_min, cam.longitude_max = (math.radians(v) for v in lon_range_deg)


def set_perspective(cam_obj: bpy.types.Object, model: CameraModel, *, scene: bpy.types.Scene | None = None) -> None:
    """Make the camera a pinhole matching ``model`` (size, fx, principal point; distortion is not rendered).

    fy must equal fx (square pixels).  The principal point (OpenCV, pixel centres at integers)
    becomes Blender's lens shift.
    """
    scene = state.get_scene(scene)
    cam = cam_obj.data
    cam.type = "PERSP"
    w, h = int(model.width), int(model.height)
    scene.render.resolution_x, scene.render.resolution_y = w, h
    scene.render.resolution_percentage = 100
    scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1.0
    if abs(float(model.fy) - float(model.fx)) > 1e-6 * float(model.fx):
        log.warning("camera fy %.3f != fx %.3f: rendered with square pixels (fx)", model.fy, model.fx)
    cam.sensor_fit = "HORIZONTAL"
    cam.sensor_width = 36.0
    cam.lens = float(model.fx) * 36.0 / w
    big = float(max(w, h))
    cam.shift_x = (w / 2.0 - (float(model.cx) + 0.5)) / big
    cam.shift_y = ((float(model.cy) + 0.5) - h / 2.0) / big
