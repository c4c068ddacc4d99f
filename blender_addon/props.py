"""Extension settings: one property group, ``Scene.skyloc`` (SKYLOC_PG_settings)."""
from __future__ import annotations

import bpy  # noqa: TID251 (extension layer)
from bpy.props import (
    BoolProperty,
    EnumProperty,
    FloatProperty,
    FloatVectorProperty,
    IntProperty,
    PointerProperty,
    StringProperty,
)

CAMERA_ITEMS = [
    ("exomars", "ExoMars NavCam", "1024 x 1024 px, 65 deg, mast 2.05 m"),
    ("mars2020", "Mars 2020 NavCam", "5120 x 3840 px, 96 deg across, mast 1.98 m"),
    ("magellium", "Magellium bench", "1600 x 1200 px, 62 x 48 deg, mast 0.75 m"),
]
PRESET_ITEMS = [
    ("binary", "Binary", "Terrain white, sky black (noise level 1)"),
    ("clean", "Clean", "Textured terrain, clear sky, no rocks or noise"),
    ("realistic", "Realistic", "Rocks, dusty sky, sensor noise (noise level 2)"),
    ("distorted", "Distorted", "Realistic plus lens distortion and dispersion (noise level 3)"),
]


class SKYLOC_PG_settings(bpy.types.PropertyGroup):
    """Everything the Skyloc panels edit; lengths in metres, angles in degrees, x/y in the DEM's CRS."""

    dem: StringProperty(name="DEM", description="GeoTIFF path or procedural:PRESET:SEED", default="procedural:mars:0",
                        subtype="NONE")
    body: StringProperty(name="Body", description="Body name or radius (m) when the DEM does not say", default="")
    site_x: FloatProperty(name="X", description="Rover / grid centre easting (DEM CRS, m)", default=0.0)
    site_y: FloatProperty(name="Y", description="Rover / grid centre northing (DEM CRS, m)", default=0.0)
    grid_half_m: FloatProperty(name="Area half-size", description="Half side of the area kept fine (m)",
                               default=200.0, min=1.0)
    max_radius_m: FloatProperty(name="Terrain radius", description="Keep terrain this far (m); 0: whole DEM",
                                default=0.0, min=0.0)
    heading_deg: FloatProperty(name="Heading", description="Degrees clockwise from grid north", default=0.0)
    pitch_deg: FloatProperty(name="Pitch", description="Nose up positive, degrees", default=0.0, min=-45, max=45)
    roll_deg: FloatProperty(name="Roll", description="Right side down positive, degrees", default=0.0, min=-45, max=45)
    mast_height_m: FloatProperty(name="Mast height", description="Camera height above the ground (m)",
                                 default=2.0, min=0.0)
    camera: EnumProperty(name="Camera", items=CAMERA_ITEMS, default="exomars")
    frame_width: IntProperty(name="Frame width", description="Render frames this wide (px); 0: the camera's own",
                             default=0, min=0, max=8192)
    frames: IntProperty(name="Frames", description="Frames of the pan-tilt plan", default=13, min=1, max=200)
    arc_deg: FloatProperty(name="Arc", description="Pan arc covered (degrees)", default=360.0, min=1.0, max=360.0)
    preset: EnumProperty(name="Look", items=PRESET_ITEMS, default="binary")
    seed: IntProperty(name="Seed", default=0, min=0)
    pano_width: IntProperty(name="Panorama width", default=2048, min=64, max=16384)
    pano_band_deg: FloatVectorProperty(name="Elevation band",
                                       description="Bottom and top elevations (degrees, mast frame) the panorama "
                                                   "covers; -90, 90 is the whole sphere, a band such as -45, 45 "
                                                   "renders only the rows where the skyline can be",
                                       size=2, default=(-90.0, 90.0), min=-90.0, max=90.0)
    out_dir: StringProperty(name="Output", description="Folder for products", default="//skyloc_out",
                            subtype="DIR_PATH")
    db_size_m: FloatProperty(name="Grid size", description="Side of the database grid (m)", default=200.0, min=0.0)
    db_step_m: FloatProperty(name="Grid step", description="Spacing of database positions (m)", default=10.0,
                             min=0.01)
    renderer: EnumProperty(name="Renderer", items=[("raymarch", "Ray-marcher", "Fast DEM ray-marcher"),
                                                   ("blender", "Blender", "Cycles binary panoramas")],
                           default="raymarch")
    use_service: BoolProperty(name="Use render service", description="Submit to the service over HTTP",
                              default=False)
    service_url: StringProperty(name="Service URL", default="http://127.0.0.1:8000")
    service_token: StringProperty(name="Token", default="", subtype="PASSWORD")
    progress: FloatProperty(name="Progress", default=0.0, min=0.0, max=1.0, subtype="FACTOR")
    status: StringProperty(name="Status", default="")
    busy: BoolProperty(name="Busy", default=False)


classes = (SKYLOC_PG_settings,)


def register() -> None:
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.Scene.skyloc = PointerProperty(type=SKYLOC_PG_settings)


def unregister() -> None:
    del bpy.types.Scene.skyloc
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
