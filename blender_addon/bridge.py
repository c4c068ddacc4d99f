"""The only translation between Blender (settings, window manager) and skyloc's dataclasses.

Holds the session's terrain (a MultiResTerrain kept between operators) and a progress reporter
that updates ``Scene.skyloc.progress``/``status`` and the window manager's progress cursor.
"""
from __future__ import annotations

import logging
import os
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path

import bpy  # noqa: TID251 (extension layer)

from blender_addon.core.acquire import Pose
from blender_addon.terrain.model import MultiResTerrain
from board.errors import InvalidInputError

log = logging.getLogger(__name__)


@dataclass
class _Session:
    terrain: MultiResTerrain | None = None
    dem_path: Path | None = None


SESSION = _Session()


def settings(context: bpy.types.Context):
    """The scene's SKYLOC_PG_settings."""
    return context.scene.skyloc


def out_dir(s) -> Path:
    """Absolute output folder (Blender's ``//`` relative paths resolved)."""
    return Path(bpy.path.abspath(s.out_dir or "//skyloc_out")).resolve()


def body_arg(s) -> str | None:
    return s.body.strip() or None


def dem_path(s) -> Path:
    """The DEM file of the settings (procedural specs synthesised once into the cache)."""
    from blender_addon.terrain.dem import resolve_dem

    if not s.dem.strip():
        raise InvalidInputError("no DEM: give a GeoTIFF path or procedural:mars:SEED in the Skyloc panel")
    spec = s.dem.strip()
    return resolve_dem(spec if spec.startswith("procedural:") else bpy.path.abspath(spec))


def site_xy(s) -> tuple[float, float]:
    return float(s.site_x), float(s.site_y)


def pose(s) -> Pose:
    """Rover pose of the settings: site x, y (DEM CRS, m), heading/pitch/roll (deg); the eye height is
    ``s.mast_height_m``."""
    return Pose(float(s.site_x), float(s.site_y), float(s.heading_deg), float(s.pitch_deg), float(s.roll_deg))


def require_terrain() -> MultiResTerrain:
    if SESSION.terrain is None:
        raise InvalidInputError("no terrain yet: press 'Build terrain' in the Skyloc panel first")
    return SESSION.terrain


def skyloc_command() -> list[str]:
    """How to run the ``skyloc`` CLI from here (Blender's Python or the venv)."""
    exe = shutil.which("skyloc")
    if exe:
        return [exe]
    return [sys.executable, "-m", "skyloc.cli"]


class Progress:
    """Context manager reporting progress to the settings and the window manager (no-op headless)."""

    def __init__(self, context: bpy.types.Context, what: str) -> None:
        self.context, self.what = context, what
        self.s = settings(context)

    def __enter__(self) -> "Progress":
        self.s.busy = True
        self.update(0.0, f"{self.what}...")
        wm = self.context.window_manager
        if wm is not None:
            wm.progress_begin(0, 100)
        return self

    def update(self, fraction: float, message: str = "") -> None:
        self.s.progress = max(0.0, min(1.0, float(fraction)))
        if message:
            self.s.status = message
        wm = self.context.window_manager
        if wm is not None:
            wm.progress_update(int(100 * self.s.progress))
        for area in getattr(self.context.screen, "areas", []) or []:
            if area.type == "VIEW_3D":
                area.tag_redraw()

    def __exit__(self, exc_type, exc, tb) -> None:
        self.s.busy = False
        wm = self.context.window_manager
        if wm is not None:
            wm.progress_end()
        if exc is None:
            self.update(1.0, f"{self.what}: done")
        else:
            self.s.status = f"{self.what}: failed ({exc})"


def fail(op: bpy.types.Operator, what: str, exc: Exception) -> set[str]:
    """Log and report an operator failure; returns {'CANCELLED'}."""
    log.error("%s failed", what, exc_info=True)
    op.report({"ERROR"}, f"{what} failed: {exc}")
    return {"CANCELLED"}


def env_for_subprocess() -> dict:
    env = dict(os.environ)
    env.setdefault("PYTHONUNBUFFERED", "1")
    return env
