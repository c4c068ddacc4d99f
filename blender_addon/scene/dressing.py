"""Scene dressing for simulated NavCam images (bpy layer): regolith, rocks, dusty sky, haze, sun.

Call :func:`dress_scene` after :func:`blender_addon.scene.build_terrain`.  It reads a
:class:`blender_addon.core.degrade.Degradation` and

* gives the terrain a regolith material: albedo with large patches (tens of metres) and small
  mottling (decimetres) of relative spread ``albedo_variation`` (no bump: it cost 25 % of render time);
* scatters rocks and pebbles around the site (:mod:`blender_addon.core.rocks`, one mesh);
* makes a Mars sky world: butterscotch, brighter at the horizon, with an aureole around the
  sun whose width and strength grow with the dust optical depth (a clear sky is a bright
  blue-white gradient, 2-3 times the sunlit regolith, for a high-contrast reference);
* fades every surface towards the horizon sky colour with distance, ``exp(-tau d / H)``
  (aerial perspective by dust), in the materials (cheap; no volume rendering);
* lights the scene with a sun lamp of angular diameter 0.35 deg dimmed by ``exp(-tau m)``
  (airmass ``m``), so low suns give long shadows and low light.

Renders are linear light: "Standard" view transform with ``-RENDER_HEADROOM_EV`` exposure so
values up to ``2 ** RENDER_HEADROOM_EV`` times full well survive in the 16-bit PNG; decode
with :func:`blender_addon.core.degrade.decode_render`.  A binary look (terrain white, sky black)
uses :func:`blender_addon.scene.configure_binary` instead.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import bpy  # noqa: TID251 (scene building is the bpy layer)
import numpy as np

from blender_addon.core import rocks as rocklib
from blender_addon.core.degrade import RENDER_HEADROOM_EV, Degradation, auto_exposure_gain
from blender_addon.core.terrain_mesh import scene_z
from blender_addon.scene import state
from blender_addon.scene.render import clear_binary, configure_binary, configure_cycles
from blender_addon.scene.terrain import TERRAIN_MATERIAL, default_material
from blender_addon.terrain.model import MultiResTerrain
from board.conventions import enu_from_az_el_deg

log = logging.getLogger(__name__)

DRESSING_COLLECTION = "SkylocDressing"
ROCK_OBJECT = "SkylocRocks"
ROCK_MATERIAL = "SkylocRockMaterial"
SUN_OBJECT = "SkylocSun"
WORLD_NAME = "SkylocMarsSky"

#: Sun irradiance (Blender sun strength, W/m2 scale) giving well-exposed frames at 0 EV.
SUN_IRRADIANCE = 5.0
#: Angular diameter of the Sun seen from Mars, degrees.
SUN_DIAMETER_DEG = 0.35
REGOLITH_RGB = np.array([0.62, 0.42, 0.28])
ROCK_RGB = np.array([0.46, 0.35, 0.28])


@dataclass(frozen=True)
class DressingInfo:
    """What :func:`dress_scene` built.

    sun_dir_enu : unit vector towards the sun (ENU); sun_azimuth_deg / sun_elevation_deg : its
    absolute direction, degrees; n_rocks : rocks placed (n_near of them near the mast);
    horizon_radiance : linear radiance of the horizon sky (full-well units before exposure)
    """

    sun_dir_enu: tuple[float, float, float]
    sun_azimuth_deg: float
    sun_elevation_deg: float
    n_rocks: int
    n_near: int
    horizon_radiance: float

    def to_dict(self) -> dict:
        return {"sun_azimuth_deg": self.sun_azimuth_deg, "sun_elevation_deg": self.sun_elevation_deg,
                "n_rocks": self.n_rocks, "n_rocks_near_mast": self.n_near,
                "horizon_radiance": self.horizon_radiance}


# ------------------------------------------------------------------------------------------------
# photometry (plain functions, documented in docs/simulator.md)
# ------------------------------------------------------------------------------------------------
def airmass(elevation_deg: float) -> float:
    """Relative airmass of a sun at ``elevation_deg`` (Kasten-Young-like, finite at the horizon)."""
    el = max(elevation_deg, -1.0)
    return 1.0 / (math.sin(math.radians(el)) + 0.15 * (el + 3.885) ** -1.253)


def sky_radiances(deg: Degradation) -> tuple[np.ndarray, np.ndarray, float]:
    """(horizon RGB, zenith RGB, aureole gain) in linear full-well units for the sky settings."""
    sun_el = deg.sun.elevation_deg
    e0 = SUN_IRRADIANCE * deg.sun.strength * auto_exposure_gain(deg)
    lift = max(math.sin(math.radians(sun_el)) + 0.08, 0.02)
    if deg.sky.black:  # airless: no sky light at all
        return np.zeros(3), np.zeros(3), 0.0
    if deg.sky.clear or deg.sky.dust_tau <= 0:
        # a bright, dust-free reference sky: 2-3 times the sunlit regolith, bluish white
        horizon = np.array([0.80, 0.86, 0.95]) * 0.25 * e0 * lift
        zenith = np.array([0.55, 0.65, 0.85]) * 0.16 * e0 * lift
        return horizon, zenith, 0.5
    tau = deg.sky.dust_tau
    scattered = 1.0 - math.exp(-tau * airmass(sun_el))
    # horizon about 0.35 of full well at tau 0.6 and 0.5 at tau 3 for a 35 deg sun (red channel)
    level = e0 * lift * (0.04 + 0.45 * scattered) / math.pi
    horizon = np.array([1.0, 0.74, 0.52]) * level
    zenith = np.array([0.85, 0.62, 0.45]) * level * (0.55 + 0.35 * (1.0 - math.exp(-tau)))
    return horizon, zenith, 0.8 + 1.5 * (1.0 - math.exp(-tau))


def sun_transmission(deg: Degradation) -> float:
    """Fraction of the sun's light reaching the ground through the dust."""
    if deg.sky.clear or deg.sky.black:
        return 1.0
    return math.exp(-deg.sky.dust_tau * airmass(deg.sun.elevation_deg))


def sun_direction(deg: Degradation, heading_deg: float = 0.0) -> tuple[float, float, np.ndarray]:
    """Absolute sun azimuth, elevation (degrees) and unit ENU vector towards the sun."""
    az = deg.sun.azimuth_deg + (heading_deg if deg.sun.relative else 0.0)
    az = float(np.mod(az, 360.0))
    el = float(deg.sun.elevation_deg)
    return az, el, np.asarray(enu_from_az_el_deg(az, el), dtype=float)


# ------------------------------------------------------------------------------------------------
# node helpers
# ------------------------------------------------------------------------------------------------


def _math(nt, op: str, a, b=None):
    n = nt.nodes.new("ShaderNodeMath")
    n.operation = op
    for i, v in enumerate((a, b)):
        if v is None:
            continue
        if isinstance(v, (int, float)):
            n.inputs[i].default_value = float(v)
        else:
            nt.links.new(v, n.inputs[i])
    return n.outputs[0]


def _mix_rgb(nt, fac, a, b, blend: str = "MIX"):
    n = nt.nodes.new("ShaderNodeMix")
    n.data_type = "RGBA"
    n.blend_type = blend
    for sock, v in ((n.inputs[0], fac), (n.inputs[6], a), (n.inputs[7], b)):
        if isinstance(v, (int, float)):
            sock.default_value = float(v)
        elif isinstance(v, (tuple, list, np.ndarray)):
            sock.default_value = (float(v[0]), float(v[1]), float(v[2]), 1.0)
        else:
            nt.links.new(v, sock)
    return n.outputs[2]


def _noise(nt, vector, scale: float, detail: float, seed_offset: float):
    """Noise texture factor (about 0.5 +- 0.2) at ``vector`` metres * scale."""
    mapping = nt.nodes.new("ShaderNodeVectorMath")
    mapping.operation = "ADD"
    nt.links.new(vector, mapping.inputs[0])
    mapping.inputs[1].default_value = (seed_offset, 2.0 * seed_offset, 0.5 * seed_offset)
    n = nt.nodes.new("ShaderNodeTexNoise")
    n.noise_dimensions = "3D"
    n.inputs["Scale"].default_value = scale
    n.inputs["Detail"].default_value = detail
    n.inputs["Roughness"].default_value = 0.55
    nt.links.new(mapping.outputs[0], n.inputs["Vector"])
    return n.outputs["Fac"]


def _haze(nt, surface, deg: Degradation, horizon_rgb: np.ndarray):
    """Mix ``surface`` with the horizon sky emission by ``exp(-tau d / H)`` (d: camera distance)."""
    tau = 0.0 if (deg.sky.clear or deg.sky.black) else deg.sky.dust_tau
    if tau <= 0:
        return surface
    cam = nt.nodes.new("ShaderNodeCameraData")
    beta = tau / deg.sky.scale_height_m
    trans = _math(nt, "EXPONENT", _math(nt, "MULTIPLY", cam.outputs["View Distance"], -beta))
    em = nt.nodes.new("ShaderNodeEmission")
    em.inputs["Color"].default_value = (*[float(c) for c in horizon_rgb], 1.0)
    em.inputs["Strength"].default_value = 1.0
    mix = nt.nodes.new("ShaderNodeMixShader")
    nt.links.new(trans, mix.inputs["Fac"])          # 0 -> haze emission, 1 -> the surface
    nt.links.new(em.outputs[0], mix.inputs[1])
    nt.links.new(surface, mix.inputs[2])
    return mix.outputs[0]


def _surface_material(mat: bpy.types.Material, deg: Degradation, base_rgb: np.ndarray, albedo: float,
                      variation: float, seed: int, horizon_rgb: np.ndarray, *, patch_m: float,
                      mottle_m: float, bump: float) -> None:
    """Rebuild ``mat`` as a textured diffuse surface with haze (kept as is when nothing changed)."""
    key = repr((deg.sky, [float(v) for v in base_rgb], albedo, variation, seed, np.round(horizon_rgb, 9).tolist(),
                patch_m, mottle_m, bump))
    if mat.get("skyloc_key") == key:
        return
    mat["skyloc_key"] = key
    if hasattr(mat, "use_nodes") and not mat.use_nodes:
        mat.use_nodes = True
    nt = mat.node_tree
    nt.nodes.clear()
    coords = nt.nodes.new("ShaderNodeTexCoord").outputs["Object"]
    so = float(seed % 997) * 13.37
    large = _noise(nt, coords, 1.0 / patch_m, 3.0, so)
    small = _noise(nt, coords, 1.0 / mottle_m, 6.0, so + 101.0)
    # albedo factor = 1 + variation * (1.6 (large - 0.5) + 1.2 (small - 0.5)), clamped
    f_large = _math(nt, "MULTIPLY", _math(nt, "SUBTRACT", large, 0.5), 1.6 * variation)
    f_small = _math(nt, "MULTIPLY", _math(nt, "SUBTRACT", small, 0.5), 1.2 * variation)
    factor = _math(nt, "MAXIMUM", _math(nt, "ADD", _math(nt, "ADD", f_large, f_small), 1.0), 0.05)
    rgb = base_rgb / max(float(np.mean(base_rgb)), 1e-6) * albedo
    color = _mix_rgb(nt, 1.0, rgb, factor, blend="MULTIPLY")
    bsdf = nt.nodes.new("ShaderNodeBsdfDiffuse")
    bsdf.inputs["Roughness"].default_value = 1.0
    nt.links.new(color, bsdf.inputs["Color"])
    if bump > 0:
        b = nt.nodes.new("ShaderNodeBump")
        b.inputs["Strength"].default_value = bump
        b.inputs["Distance"].default_value = 0.05
        nt.links.new(small, b.inputs["Height"])
        nt.links.new(b.outputs["Normal"], bsdf.inputs["Normal"])
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(_haze(nt, bsdf.outputs[0], deg, horizon_rgb), out.inputs["Surface"])


def _world(scene: bpy.types.Scene, deg: Degradation, sun_enu: np.ndarray) -> None:
    """Sky: horizon/zenith gradient in elevation plus an aureole around the sun."""
    world = bpy.data.worlds.get(WORLD_NAME) or bpy.data.worlds.new(WORLD_NAME)
    key = repr((deg.sky, deg.sun.elevation_deg, deg.sun.strength, auto_exposure_gain(deg),
                np.round(sun_enu, 9).tolist()))
    scene.world = world
    if world.get("skyloc_key") == key:     # unchanged: keep it (Cycles keeps its light importance map)
        return
    world["skyloc_key"] = key
    # the sky is smooth (gradient + a >10 deg aureole): a 256 px importance map is plenty and
    # 16 times cheaper to rebuild than Blender's default 1024
    world.cycles.sampling_method = "MANUAL"
    world.cycles.sample_map_resolution = 256
    if hasattr(world, "use_nodes") and not world.use_nodes:
        world.use_nodes = True
    nt = world.node_tree
    nt.nodes.clear()
    horizon, zenith, aureole = sky_radiances(deg)
    direction = nt.nodes.new("ShaderNodeTexCoord").outputs["Generated"]
    norm = nt.nodes.new("ShaderNodeVectorMath")
    norm.operation = "NORMALIZE"
    nt.links.new(direction, norm.inputs[0])
    sep = nt.nodes.new("ShaderNodeSeparateXYZ")
    nt.links.new(norm.outputs[0], sep.inputs[0])
    up = _math(nt, "MAXIMUM", sep.outputs["Z"], 0.0)
    # gradient: 0 at the horizon, -> 1 towards the zenith (e-folding at ~10 deg of elevation)
    grad = _math(nt, "SUBTRACT", 1.0, _math(nt, "EXPONENT", _math(nt, "MULTIPLY", up, -5.5)))
    sky = _mix_rgb(nt, grad, horizon, zenith)
    # aureole: gain * exp(40 (cos(angle) - 1)) times the horizon colour, bluish near the sun when dusty
    dot = nt.nodes.new("ShaderNodeVectorMath")
    dot.operation = "DOT_PRODUCT"
    nt.links.new(norm.outputs[0], dot.inputs[0])
    dot.inputs[1].default_value = tuple(float(v) for v in sun_enu)
    width = 40.0 if deg.sky.clear else 40.0 / (1.0 + 0.5 * deg.sky.dust_tau)
    glow = _math(nt, "EXPONENT", _math(nt, "MULTIPLY", _math(nt, "SUBTRACT", dot.outputs["Value"], 1.0), width))
    glow = _math(nt, "MULTIPLY", glow, aureole)
    tint = np.array([0.75, 0.85, 1.0]) * float(np.mean(horizon))
    sky = _mix_rgb(nt, 1.0, sky, _mix_rgb(nt, glow, (0.0, 0.0, 0.0), tint), blend="ADD")
    bg = nt.nodes.new("ShaderNodeBackground")
    bg.inputs["Strength"].default_value = 1.0
    nt.links.new(sky, bg.inputs["Color"])
    out = nt.nodes.new("ShaderNodeOutputWorld")
    nt.links.new(bg.outputs[0], out.inputs["Surface"])


def _sun(scene: bpy.types.Scene, deg: Degradation, sun_enu: np.ndarray) -> None:
    obj = bpy.data.objects.get(SUN_OBJECT)
    if obj is None:
        light = bpy.data.lights.new(SUN_OBJECT, "SUN")
        obj = bpy.data.objects.new(SUN_OBJECT, light)
        scene.collection.objects.link(obj)
    light = obj.data
    light.angle = math.radians(SUN_DIAMETER_DEG)
    light.energy = (SUN_IRRADIANCE * deg.sun.strength * auto_exposure_gain(deg) * sun_transmission(deg)
                    if deg.sun.elevation_deg > -0.5 else 0.0)
    light.color = (1.0, 0.97, 0.92)
    # the lamp shines along its local -Z: point -Z away from the sun
    from mathutils import Vector

    obj.rotation_mode = "QUATERNION"
    obj.rotation_quaternion = Vector(tuple(float(v) for v in sun_enu)).to_track_quat("Z", "Y")


def _triangle_mesh(name: str, verts: np.ndarray, tris: np.ndarray) -> bpy.types.Mesh:
    me = bpy.data.meshes.new(name)
    me.vertices.add(len(verts))
    me.vertices.foreach_set("co", np.ascontiguousarray(verts, dtype=np.float32).ravel())
    me.loops.add(3 * len(tris))
    me.loops.foreach_set("vertex_index", np.ascontiguousarray(tris, dtype=np.int32).ravel())
    me.polygons.add(len(tris))
    me.polygons.foreach_set("loop_start", np.arange(0, 3 * len(tris), 3, dtype=np.int32))
    me.update(calc_edges=True)     # flat shading: faceted, angular rocks
    return me


def sun_visible(x: float, y: float, z: float, sun_enu, *, scene: bpy.types.Scene | None = None) -> bool:
    """True when nothing in the scene (terrain, rocks) hides the sun from world point (x, y, z) metres.

    Veiling glare only exists when sunlight reaches the lens; a sun behind a hill makes none.
    """
    scene = state.get_scene(scene)
    off = state.get_offset(scene)
    radius, k = state.get_curvature(scene)
    from mathutils import Vector

    origin = Vector((x - off.x_m, y - off.y_m, float(scene_z(z, x, y, off, radius, k))))
    direction = Vector(tuple(float(v) for v in sun_enu)).normalized()
    depsgraph = bpy.context.evaluated_depsgraph_get()
    hit = scene.ray_cast(depsgraph, origin + direction * 0.05, direction)[0]
    return not hit


def clear_dressing(scene: bpy.types.Scene | None = None) -> None:
    """Remove the rocks (the materials, world and sun are rebuilt in place by :func:`dress_scene`)."""
    state.remove_collection_objects(DRESSING_COLLECTION)


def _place_rocks(scene, terrain: MultiResTerrain, deg: Degradation, center_xy, rng: np.random.Generator,
                 horizon_rgb) -> tuple[int, int]:
    r = deg.rocks
    field = rocklib.place_rocks(center_xy, rng, density_per_m2=r.density_per_m2, d_min_m=r.d_min_m,
                                d_max_m=r.d_max_m, exponent=r.exponent, radius_m=r.radius_m,
                                near_count=r.near_count, near_distance_m=r.near_distance_m,
                                near_diameter_m=r.near_diameter_m)
    if len(field) == 0:
        return 0, 0
    lev = terrain.finest
    ground = rocklib.bilinear_height(lev.array, lev.x0, lev.y0, lev.cell_m, field.x, field.y)
    verts, tris = rocklib.rock_mesh(field, ground, rng)
    off = state.get_offset(scene)
    radius, k = state.get_curvature(scene)
    world_x = verts[:, 0].astype(np.float64)
    world_y = verts[:, 1].astype(np.float64)
    verts = np.column_stack([world_x - off.x_m, world_y - off.y_m,
                             scene_z(verts[:, 2].astype(np.float64), world_x, world_y, off, radius, k)])
    coll = bpy.data.collections.get(DRESSING_COLLECTION) or bpy.data.collections.new(DRESSING_COLLECTION)
    if coll.name not in scene.collection.children:
        scene.collection.children.link(coll)
    me = _triangle_mesh(ROCK_OBJECT, verts, tris)
    mat = bpy.data.materials.get(ROCK_MATERIAL) or bpy.data.materials.new(ROCK_MATERIAL)
    _surface_material(mat, deg, ROCK_RGB, 0.5 * deg.regolith_albedo, 0.5, 1,
                      horizon_rgb, patch_m=0.8, mottle_m=0.05, bump=0.4)
    me.materials.append(mat)
    obj = bpy.data.objects.new(ROCK_OBJECT, me)
    coll.objects.link(obj)
    return len(field), int(field.near.sum())


def dress_scene(terrain: MultiResTerrain, deg: Degradation, *, center_xy: tuple[float, float],
                heading_deg: float = 0.0, seed: int = 0, texture_seed: int = 0, samples: int = 16,
                denoise: bool = False, scene: bpy.types.Scene | None = None) -> DressingInfo:
    """Dress the built terrain for one look and configure Cycles; returns what was placed.

    center_xy : rover position (metres, the DEM's CRS), centre of the rock field
    heading_deg : rover heading, for a sun given relative to it
    seed : rocks and the Cycles sampling seed (one per acquisition)
    texture_seed : regolith texture (a property of the site: keep it fixed across acquisitions)
    samples : Cycles samples per pixel, at least; the noisy ones (the skyline's edge) get up to
        :data:`~blender_addon.scene.render.ADAPTIVE_MAX_FACTOR` times more (binary looks use 1, exactly)

    The world and the regolith material are rebuilt only when their parameters change, so
    successive acquisitions with the same look skip Cycles' shader and sky-map updates.
    """
    scene = state.get_scene(scene)
    clear_dressing(scene)
    az, el, sun_enu = sun_direction(deg, heading_deg)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x5CE]))
    if deg.binary:
        n, n_near = _place_rocks(scene, terrain, deg, center_xy, rng, np.zeros(3))
        configure_binary(scene, samples=1)
        return DressingInfo(tuple(float(v) for v in sun_enu), az, el, n, n_near, 0.0)
    clear_binary(scene)
    configure_cycles(scene, samples=samples, denoise=denoise, adaptive=True)
    c = scene.cycles
    c.seed = int(seed) % (1 << 31)
    c.use_animated_seed = False
    c.max_bounces = 4
    c.diffuse_bounces = 2
    c.glossy_bounces = c.transmission_bounces = c.volume_bounces = c.transparent_max_bounces = 0
    c.caustics_reflective = c.caustics_refractive = False
    c.use_light_tree = False          # one sun and the sky: the tree only costs time (7 %)
    c.pixel_filter_type = "BLACKMAN_HARRIS"
    c.filter_width = 1.5
    scene.render.film_transparent = False
    scene.render.dither_intensity = 0.0
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = -float(RENDER_HEADROOM_EV)
    scene.view_settings.gamma = 1.0
    scene.display_settings.display_device = "sRGB"
    horizon, _, _ = sky_radiances(deg)
    mat = bpy.data.materials.get(TERRAIN_MATERIAL) or default_material()
    _surface_material(mat, deg, REGOLITH_RGB, deg.regolith_albedo, deg.albedo_variation, int(texture_seed),
                      horizon, patch_m=25.0, mottle_m=0.4, bump=0.0)   # bump: +25 % render time, little gain
    _world(scene, deg, sun_enu)
    _sun(scene, deg, sun_enu)
    n, n_near = _place_rocks(scene, terrain, deg, center_xy, rng, horizon)
    log.info("dressed: %s, sun az %.1f el %.1f, %d rocks (%d near the mast)", deg.name, az, el, n, n_near)
    return DressingInfo(tuple(float(v) for v in sun_enu), az, el, n, n_near, float(np.mean(horizon)))
