"""The Blender path of the descent simulator: the fast renderer's scene as a Cycles scene, for artists.

The terrain's node grid becomes one quad mesh (world metres, no offset: the descent terrain is a
local frame); its normals, albedo, temperature and shadow maps become float image textures sampled
bilinearly at the same places as the fast renderer (UV ``((ix + 0.5) / nx, (iy + 0.5) / ny)`` at node
``(ix, iy)``, image pixel centres on the nodes); a window of the terrain can be built instead of all
of it.  Two emission-only materials:

* visible: the memorandum's eq. 9 built from shader nodes (the Geometry node's *Incoming* vector
  is V, the lights are constant vectors), ``E = ambient rho + sum_s w_s [alpha rho max(N.L, 0) +
  (1 - alpha) rho_s max(R.V, 0)^k [N.L > 0]] lit_s``, exactly :func:`blender_addon.descent.brdf.eq9`;
* thermal: the temperature map (K) as the emission strength.

Cycles renders them with camera rays only (no bounces, black world, Standard view transform, one
sample at the pixel centre) into float EXR, so a pixel holds the brightness or the kelvin value.
Only the eq. 9 BRDF has a node version (Hapke is the fast renderer's alone).
"""
from __future__ import annotations

import logging
import tempfile
from pathlib import Path

import bpy  # noqa: TID251 (scene building is the bpy layer)
import numpy as np
from mathutils import Matrix

from blender_addon.descent.constants import SUN_IRRADIANCE_W_M2
from blender_addon.descent.render import DescentRenderer
from blender_addon.scene.camera import set_perspective
from blender_addon.scene.quiet import native_stdout_captured
from blender_addon.scene.terrain import mesh_from_arrays
from board.descent.sequence import DescentCamera
from board.errors import InvalidInputError

log = logging.getLogger(__name__)

DESCENT_COLLECTION = "SkylocDescent"
TERRAIN_OBJECT = "SkylocDescentTerrain"
CAMERA_OBJECT = "SkylocDescentCamera"
TRAJECTORY_OBJECT = "SkylocDescentTrajectory"
#: OpenCV camera axes (x right, y down, z forward) -> Blender camera axes (x right, y up, z backward).
_CV_TO_BLENDER = np.diag([1.0, -1.0, -1.0])


def _image(name: str, grid: np.ndarray) -> bpy.types.Image:
    """A float, non-colour image holding ``grid`` (ny, nx) or (ny, nx, 3); row 0 = the bottom (south)."""
    g = np.asarray(grid, dtype=np.float32)
    ny, nx = g.shape[:2]
    rgba = np.ones((ny, nx, 4), np.float32)
    if g.ndim == 2:
        rgba[..., :3] = g[..., None]
    else:
        rgba[..., :3] = g
    img = bpy.data.images.get(name)
    if img is not None:
        bpy.data.images.remove(img)
    img = bpy.data.images.new(name, width=nx, height=ny, alpha=True, float_buffer=True)
    img.colorspace_settings.name = "Non-Color"
    img.pixels.foreach_set(rgba.ravel())
    img.pack()
    return img


def _window(renderer: DescentRenderer, window) -> tuple[slice, slice]:
    """Node index slices (rows, cols) of the world window (xmin, ymin, xmax, ymax) m, or the whole grid."""
    tr = renderer.terrain
    ny, nx = tr.shape
    if window is None:
        return slice(0, ny), slice(0, nx)
    xmin, ymin, xmax, ymax = window
    c0 = max(int(np.floor((xmin - tr.x0) / tr.res_m)), 0)
    c1 = min(int(np.ceil((xmax - tr.x0) / tr.res_m)) + 1, nx)
    r0 = max(int(np.floor((ymin - tr.y0) / tr.res_m)), 0)
    r1 = min(int(np.ceil((ymax - tr.y0) / tr.res_m)) + 1, ny)
    if c1 - c0 < 2 or r1 - r0 < 2:
        raise InvalidInputError(f"window {window} m does not overlap the terrain {tr.bounds}")
    return slice(r0, r1), slice(c0, c1)


def _mesh(renderer: DescentRenderer, win: tuple[slice, slice]) -> bpy.types.Object:
    tr = renderer.terrain
    height = tr.height[win]
    ny, nx = height.shape
    ix, iy = np.meshgrid(np.arange(win[1].start, win[1].stop), np.arange(win[0].start, win[0].stop))
    verts = np.stack([tr.x0 + ix * tr.res_m, tr.y0 + iy * tr.res_m, height], axis=-1).reshape(-1, 3)
    idx = np.arange(nx * ny).reshape(ny, nx)
    quads = np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]], axis=-1).reshape(-1, 4)
    me = mesh_from_arrays(TERRAIN_OBJECT, verts, quads)
    uv = me.uv_layers.new(name="grid")
    loop_vert = np.empty(len(me.loops), np.int32)
    me.loops.foreach_get("vertex_index", loop_vert)
    u = (loop_vert % nx + 0.5) / nx
    v = (loop_vert // nx + 0.5) / ny
    uv.data.foreach_set("uv", np.stack([u, v], axis=-1).astype(np.float32).ravel())
    obj = bpy.data.objects.new(TERRAIN_OBJECT, me)
    return obj


class _Nodes:
    """Small helper to build a node tree with math nodes."""

    def __init__(self, tree: bpy.types.NodeTree) -> None:
        self.tree = tree

    def node(self, kind: str, **props):
        n = self.tree.nodes.new(kind)
        for k, v in props.items():
            setattr(n, k, v)
        return n

    def link(self, out, inp) -> None:
        self.tree.links.new(out, inp)

    def math(self, op: str, a, b=None):
        n = self.node("ShaderNodeMath", operation=op)
        for i, x in enumerate((a, b)):
            if x is None:
                continue
            if isinstance(x, (int, float)):
                n.inputs[i].default_value = float(x)
            else:
                self.link(x, n.inputs[i])
        return n.outputs[0]

    def dot(self, a, b):
        n = self.node("ShaderNodeVectorMath", operation="DOT_PRODUCT")
        for i, x in enumerate((a, b)):
            if isinstance(x, (tuple, list, np.ndarray)):
                n.inputs[i].default_value = tuple(float(c) for c in x)
            else:
                self.link(x, n.inputs[i])
        return n.outputs["Value"]

    def texture(self, image: bpy.types.Image, uv):
        n = self.node("ShaderNodeTexImage", image=image, interpolation="Linear", extension="EXTEND")
        self.link(uv, n.inputs["Vector"])
        return n.outputs["Color"]

    def red(self, color):
        n = self.node("ShaderNodeSeparateColor")
        self.link(color, n.inputs["Color"])
        return n.outputs[0]

    def emit(self, strength) -> None:
        em = self.node("ShaderNodeEmission")
        em.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
        self.link(strength, em.inputs["Strength"])
        out = self.node("ShaderNodeOutputMaterial")
        self.link(em.outputs["Emission"], out.inputs["Surface"])


def _material(name: str) -> tuple[bpy.types.Material, _Nodes, object]:
    mat = bpy.data.materials.get(name) or bpy.data.materials.new(name)
    mat.use_nodes = True
    mat.node_tree.nodes.clear()
    nodes = _Nodes(mat.node_tree)
    uv = nodes.node("ShaderNodeUVMap", uv_map="grid").outputs["UV"]
    return mat, nodes, uv


def visible_material(renderer: DescentRenderer, win: tuple[slice, slice]) -> bpy.types.Material:
    """Emission material computing eq. 9 per shading point (see the module docstring)."""
    o = renderer.options
    if o.brdf != "tm":
        raise InvalidInputError(f"the Blender path renders the memorandum's eq. 9 only, not {o.brdf!r}: use --brdf tm")
    mat, nd, uv = _material("SkylocDescentVisible")
    g = {k: v[win] for k, v in renderer.grids.items()}
    nrm = nd.node("ShaderNodeVectorMath", operation="NORMALIZE")
    nd.link(nd.texture(_image("descent_normals", np.stack([g["nx"], g["ny"], g["nz"]], axis=-1)), uv),
            nrm.inputs[0])
    n = nrm.outputs["Vector"]
    rho = nd.red(nd.texture(_image("descent_albedo", g["albedo"]), uv))
    v = nd.node("ShaderNodeNewGeometry").outputs["Incoming"]
    ndv = nd.dot(n, v)
    total = nd.math("MULTIPLY", rho, o.ambient)
    for s in renderer.visible_lights:
        ndl = nd.dot(n, s.direction)
        cos_g = nd.dot(v, s.direction)
        alpha = nd.math("MULTIPLY", nd.math("ADD", cos_g, 1.0), 0.5)
        diffuse = nd.math("MULTIPLY", nd.math("MULTIPLY", alpha, rho), nd.math("MAXIMUM", ndl, 0.0))
        rdv = nd.math("SUBTRACT", nd.math("MULTIPLY", nd.math("MULTIPLY", ndl, ndv), 2.0), cos_g)
        spec = nd.math("POWER", nd.math("MAXIMUM", rdv, 0.0), o.k_phong)
        spec = nd.math("MULTIPLY", nd.math("MULTIPLY", spec, nd.math("SUBTRACT", 1.0, alpha)), o.rho_s)
        spec = nd.math("MULTIPLY", spec, nd.math("GREATER_THAN", ndl, 0.0))
        term = nd.math("ADD", diffuse, spec)
        if s.name in renderer.lit:
            term = nd.math("MULTIPLY", term, nd.red(nd.texture(_image(f"descent_lit_{s.name}",
                                                                      renderer.lit[s.name][win]), uv)))
        total = nd.math("ADD", total, nd.math("MULTIPLY", term, s.irradiance_w_m2 / SUN_IRRADIANCE_W_M2))
    nd.emit(total)
    return mat


def thermal_material(renderer: DescentRenderer, win: tuple[slice, slice]) -> bpy.types.Material:
    """Emission material whose strength is the temperature map (K)."""
    mat, nd, uv = _material("SkylocDescentThermal")
    nd.emit(nd.red(nd.texture(_image("descent_temperature", renderer.temperature[win]), uv)))
    return mat


def clear_descent_scene() -> None:
    """Remove what :func:`build_descent_scene` added (terrain, camera, trajectory curve) from the session."""
    for name in (TERRAIN_OBJECT, CAMERA_OBJECT, TRAJECTORY_OBJECT):
        obj = bpy.data.objects.get(name)
        if obj is not None:
            data = obj.data
            bpy.data.objects.remove(obj)
            if data is not None and data.users == 0:
                for coll in (bpy.data.meshes, bpy.data.cameras, bpy.data.curves):
                    if data.name in coll and coll[data.name] == data:
                        coll.remove(data)
                        break
    coll = bpy.data.collections.get(DESCENT_COLLECTION)
    if coll is not None:
        bpy.data.collections.remove(coll)


def build_descent_scene(renderer: DescentRenderer, *, window=None, reset: bool = True) -> bpy.types.Scene:
    """Build the terrain, both materials, a black world and Cycles set for emission in the current scene.

    window : (xmin, ymin, xmax, ymax) world metres of terrain to build (None: all of it; a 400 m
    terrain at 0.25 m is 2.6 million vertices, so give the frames' footprint when you can).
    reset : empty the session first (factory settings); the add-on passes False and only the
    previous descent objects are replaced.
    """
    if renderer.options.brdf != "tm":
        raise InvalidInputError(f"the Blender path renders the memorandum's eq. 9 only, not "
                                f"{renderer.options.brdf!r}: use --brdf tm")
    if reset:
        bpy.ops.wm.read_factory_settings(use_empty=True)
    else:
        clear_descent_scene()
    scene = bpy.context.scene
    coll = bpy.data.collections.new(DESCENT_COLLECTION)
    scene.collection.children.link(coll)
    win = _window(renderer, window)
    obj = _mesh(renderer, win)
    coll.objects.link(obj)
    obj.data.materials.append(visible_material(renderer, win))
    thermal_material(renderer, win)
    world = bpy.data.worlds.new("SkylocDescentWorld")
    world.use_nodes = True
    bg = world.node_tree.nodes.get("Background")
    if bg is not None:
        bg.inputs["Strength"].default_value = 0.0
    scene.world = world
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 1
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = False
    scene.cycles.max_bounces = 0
    scene.cycles.filter_width = 0.01
    scene.cycles.seed = 0
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    scene.render.use_compositing = False
    scene.render.use_sequencer = False
    scene.render.film_transparent = False
    s = scene.render.image_settings
    s.file_format = "OPEN_EXR"
    s.color_depth = "32"
    s.color_mode = "RGB"
    cam = bpy.data.cameras.new(CAMERA_OBJECT)
    cam.clip_start = 0.05
    cam.clip_end = 1.0e5
    cam_obj = bpy.data.objects.new(CAMERA_OBJECT, cam)
    coll.objects.link(cam_obj)
    scene.camera = cam_obj
    return scene


def place_descent_camera(cam: DescentCamera, R_wb, p_wb) -> bpy.types.Object:
    """Move the scene camera to the body pose (R_world_body, body origin in m) through the camera extrinsics."""
    obj = bpy.data.objects[CAMERA_OBJECT]
    R_wc = np.asarray(R_wb, dtype=np.float64) @ cam.R_body_cam
    m = np.eye(4)
    m[:3, :3] = R_wc @ _CV_TO_BLENDER
    m[:3, 3] = np.asarray(p_wb, dtype=np.float64) + np.asarray(R_wb, dtype=np.float64) @ cam.t_body_cam
    obj.matrix_world = Matrix(m.tolist())
    set_perspective(obj, cam.model)
    return obj


def show_trajectory(points: np.ndarray) -> bpy.types.Object:
    """A poly-line curve object through the (n, 3) world points of a trajectory (replaces the previous one)."""
    old = bpy.data.objects.get(TRAJECTORY_OBJECT)
    if old is not None:
        curve = old.data
        bpy.data.objects.remove(old)
        bpy.data.curves.remove(curve)
    curve = bpy.data.curves.new(TRAJECTORY_OBJECT, type="CURVE")
    curve.dimensions = "3D"
    spline = curve.splines.new("POLY")
    pts = np.asarray(points, dtype=np.float64)
    spline.points.add(len(pts) - 1)
    co = np.column_stack([pts, np.ones(len(pts))]).astype(np.float32)
    spline.points.foreach_set("co", co.ravel())
    obj = bpy.data.objects.new(TRAJECTORY_OBJECT, curve)
    coll = bpy.data.collections.get(DESCENT_COLLECTION)
    (coll or bpy.context.scene.collection).objects.link(obj)
    return obj


def _read_exr(path: Path) -> np.ndarray:
    img = bpy.data.images.load(str(path))
    try:
        w, h = img.size
        px = np.empty(w * h * 4, np.float32)
        img.pixels.foreach_get(px)
        return px.reshape(h, w, 4)[::-1, :, 0].astype(np.float64)
    finally:
        bpy.data.images.remove(img)


def render_pair(cam: DescentCamera, R_wb, p_wb) -> dict[str, np.ndarray]:
    """{"visible": brightness, "thermal": K}, each (H, W) float64, rendered by Cycles (0 where no terrain)."""
    scene = bpy.context.scene
    place_descent_camera(cam, R_wb, p_wb)
    obj = bpy.data.objects[TERRAIN_OBJECT]
    out = {}
    with tempfile.TemporaryDirectory(prefix="skyloc-descent-") as tmp:
        for mode, mat in (("visible", "SkylocDescentVisible"), ("thermal", "SkylocDescentThermal")):
            obj.data.materials[0] = bpy.data.materials[mat]
            path = Path(tmp) / f"{mode}.exr"
            scene.render.filepath = str(path)
            scene.render.use_file_extension = False
            with native_stdout_captured() as said:        # Blender prints "Saved: ..." on fd 1
                bpy.ops.render.render(write_still=True, scene=scene.name)
            if not path.is_file():
                raise RuntimeError(f"Blender did not write {path}; it printed: {said.text.strip() or '(nothing)'}")
            out[mode] = _read_exr(path)
        obj.data.materials[0] = bpy.data.materials["SkylocDescentVisible"]
    return out
