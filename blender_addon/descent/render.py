"""The fast bpy-free descent renderer: one height-field ray cast per pixel feeds both cameras.

For a body pose (``R_wb`` body -> world, ``p_wb`` body origin in the world, metres) each pixel's
ray (the camera model's unprojection, rotated by ``R_wb R_body_cam``) is cast against the bilinear
terrain (:func:`_raycast.cast_rays`); at the hit the node grids are sampled bilinearly: the normal,
the albedo, the precomputed temperature map and the cast-shadow maps.  The visible brightness is
the chosen BRDF summed over the lights (weights ``E_s / E_sun``), the thermal value is the surface
temperature (K).  Pixels that see no terrain are NaN.  Co-registered cameras (same model and
extrinsics) share the ray cast, so the same ground point lands on the same pixel by construction.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from board.descent.sequence import DescentCamera
from board.errors import InvalidInputError

from . import _raycast
from .brdf import HapkeParams, hapke_brightness, quasi_phong
from .constants import EUROPA_ALBEDO, SUN_IRRADIANCE_W_M2
from .lights import Light
from .terrain import DescentTerrain
from .thermal import conduction_temperature_map, instantaneous_temperature

log = logging.getLogger(__name__)

BRDFS = ("tm", "hapke")
THERMAL_MODELS = ("tm", "conduction")
_BLOCK = 16


@dataclass(frozen=True)
class AppearanceOptions:
    """brdf : "tm" (eq. 9) or "hapke"; thermal : "tm" (instantaneous + smoothing) or "conduction";
    shadows : cast shadows (default: on with Hapke, off with eq. 9 as in the memorandum);
    rho_s, k_phong : eq. 9's specular albedo and sharpness; ambient : rho_a / rho_d (memorandum: 1);
    smoothing_passes : the tm model's box passes; thermal_inertia : SI, for conduction."""

    brdf: str = "tm"
    thermal: str = "tm"
    shadows: bool | None = None
    rho_s: float = 0.2
    k_phong: float = 10.0
    ambient: float = 1.0
    smoothing_passes: int = 3
    thermal_inertia: float = 70.0
    hapke: HapkeParams = HapkeParams()

    def __post_init__(self) -> None:
        if self.brdf not in BRDFS:
            raise InvalidInputError(f"brdf {self.brdf!r}: use one of {', '.join(BRDFS)}")
        if self.thermal not in THERMAL_MODELS:
            raise InvalidInputError(f"thermal model {self.thermal!r}: use one of {', '.join(THERMAL_MODELS)}")

    @property
    def cast_shadows(self) -> bool:
        return (self.brdf == "hapke") if self.shadows is None else bool(self.shadows)


def _merge_visible_lights(lights: list[Light], shadowed: set[str]) -> list[Light]:
    """The sources the visible camera sees, those sharing a direction merged (irradiances added).

    A source with its own shadow map is kept apart (its name selects the map)."""
    out: list[Light] = []
    for s in lights:
        if s.kind == "thermal" or s.irradiance_w_m2 <= 0:
            continue
        for i, o in enumerate(out):
            if (o.name not in shadowed and s.name not in shadowed
                    and np.allclose(o.direction, s.direction, atol=1e-9)):
                out[i] = Light(o.name, o.azimuth_deg, o.elevation_deg, o.irradiance_w_m2 + s.irradiance_w_m2,
                               o.apparent_diameter_arcmin, o.kind)
                break
        else:
            out.append(s)
    return out


class DescentRenderer:
    """Precomputed scene (normals, shadow maps, temperature map) and the per-frame renderer."""

    def __init__(self, terrain: DescentTerrain, lights: list[Light], options: AppearanceOptions = AppearanceOptions(),
                 *, step_m: float | None = None) -> None:
        self.terrain = terrain
        self.lights = list(lights)
        self.options = options
        self.step_m = 0.5 * terrain.res_m if step_m is None else float(step_m)
        h = terrain.height
        self._bmax = _raycast.block_max(h, _BLOCK)
        self._zrange = (float(h.min()), float(h.max()))
        self.normals = terrain.normals()
        self.lit: dict[str, np.ndarray] = {}
        if options.cast_shadows:
            for s in self.lights:
                if s.kind == "thermal" or s.irradiance_w_m2 <= 0:
                    continue
                out = np.empty(h.shape, np.float32)
                _raycast.shadow_map(h, terrain.x0, terrain.y0, terrain.res_m, s.direction, terrain.res_m,
                                    0.05, out)
                self.lit[s.name] = out
        if options.thermal == "tm":
            self.temperature = instantaneous_temperature(self.normals, self.lights, lit=self.lit or None,
                                                         passes=options.smoothing_passes).astype(np.float32)
        else:
            self.temperature = conduction_temperature_map(self.normals, self.lights,
                                                          thermal_inertia=options.thermal_inertia).astype(np.float32)
        #: node grids sampled at the hits (the Blender path turns them into textures)
        self.grids = {"nx": np.ascontiguousarray(self.normals[..., 0]),
                       "ny": np.ascontiguousarray(self.normals[..., 1]),
                       "nz": np.ascontiguousarray(self.normals[..., 2]),
                       "albedo": terrain.albedo, "temperature": self.temperature,
                       **{f"lit:{k}": v for k, v in self.lit.items()}}
        self._rays_cam: dict[int, np.ndarray] = {}
        #: the sources of the visible channel, those sharing a direction merged
        self.visible_lights = _merge_visible_lights(self.lights, set(self.lit))
        log.info("descent renderer: %s terrain, brdf %s, thermal %s, shadows %s, T %.1f-%.1f K",
                 terrain.spec, options.brdf, options.thermal, options.cast_shadows, self.temperature.min(),
                 self.temperature.max())

    # -- geometry -----------------------------------------------------------------------------
    def _camera_rays(self, cam: DescentCamera) -> np.ndarray:
        key = hash((cam.model, cam.R_body_cam.tobytes(), cam.t_body_cam.tobytes()))
        if key not in self._rays_cam:
            u, v = cam.model.pixel_grid()
            self._rays_cam[key] = cam.model.unproject(u, v).reshape(-1, 3)
        return self._rays_cam[key]

    def cast(self, cam: DescentCamera, R_wb: np.ndarray, p_wb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World ray directions (N, 3), camera centre (3,) and hit distances (N,) (m, NaN = miss) of every pixel."""
        R_wc = np.asarray(R_wb, dtype=np.float64) @ cam.R_body_cam
        origin = np.asarray(p_wb, dtype=np.float64) + np.asarray(R_wb, dtype=np.float64) @ cam.t_body_cam
        dirs = np.ascontiguousarray(self._camera_rays(cam) @ R_wc.T)
        t = np.empty(dirs.shape[0])
        tr = self.terrain
        _raycast.cast_rays(tr.height, self._bmax, _BLOCK, tr.x0, tr.y0, tr.res_m, *self._zrange, origin, dirs,
                           self.step_m, t)
        return dirs, origin, t

    def range_along(self, origin, direction) -> float:
        """Distance (m) from ``origin`` along the unit ``direction`` to the terrain (NaN = miss)."""
        t = np.empty(1)
        tr = self.terrain
        _raycast.cast_rays(tr.height, self._bmax, _BLOCK, tr.x0, tr.y0, tr.res_m, *self._zrange,
                           np.asarray(origin, dtype=np.float64),
                           np.ascontiguousarray(np.asarray(direction, dtype=np.float64).reshape(1, 3)), self.step_m, t)
        return float(t[0])

    def sample(self, name: str, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
        """Bilinear value of a scene grid ("nx", "ny", "nz", "albedo", "temperature", "lit:NAME") at world points."""
        out = np.empty(xs.shape[0])
        tr = self.terrain
        _raycast.sample_bilinear(self.grids[name], tr.x0, tr.y0, tr.res_m, np.ascontiguousarray(xs, np.float64),
                                 np.ascontiguousarray(ys, np.float64), out)
        return out

    # -- appearance -----------------------------------------------------------------------------
    def shade_visible(self, n: np.ndarray, v: np.ndarray, albedo: np.ndarray, lit: dict[str, np.ndarray]) -> np.ndarray:
        """Visible brightness (unitless) of facets: normals n (N, 3), unit vectors to the viewer v (N, 3)."""
        o = self.options
        if o.brdf == "tm":
            e = o.ambient * albedo
        else:
            e = np.zeros(albedo.shape)
        for s in self.visible_lights:
            w = s.irradiance_w_m2 / SUN_IRRADIANCE_W_M2
            shade = lit.get(s.name, 1.0)
            if o.brdf == "tm":
                e += w * quasi_phong(n, s.direction, v, rho_a=0.0, rho_d=albedo, rho_s=o.rho_s, k=o.k_phong, lit=shade)
            else:
                e += w * hapke_brightness(n, s.direction, v, o.hapke, lit=shade) * (albedo / EUROPA_ALBEDO)
        return e

    def render(self, cam: DescentCamera, R_wb, p_wb) -> dict[str, np.ndarray]:
        """One frame of both channels: {"visible": brightness, "thermal": K, "range": m along the ray,
        "x", "y", "z": hit point (m)}, each (H, W) float, NaN where the pixel sees no terrain.

        Eq. 9 runs in the fused numba kernel; Hapke in numpy (:meth:`render_reference`)."""
        if self.options.brdf != "tm":
            return self.render_reference(cam, R_wb, p_wb)
        R_wc = np.asarray(R_wb, dtype=np.float64) @ cam.R_body_cam
        origin = np.asarray(p_wb, dtype=np.float64) + np.asarray(R_wb, dtype=np.float64) @ cam.t_body_cam
        dirs = np.ascontiguousarray(self._camera_rays(cam) @ R_wc.T)
        n = dirs.shape[0]
        out = {k: np.empty(n) for k in ("range", "visible", "thermal", "x", "y")}
        tr = self.terrain
        g = self.grids
        lights = self.visible_lights
        lit = (np.stack([self.lit[s.name] for s in lights]) if self.lit
               else np.ones((len(lights), 1, 1), np.float32))
        o = self.options
        _raycast.render_eq9(tr.height, self._bmax, _BLOCK, tr.x0, tr.y0, tr.res_m, *self._zrange, origin, dirs,
                            self.step_m, g["nx"], g["ny"], g["nz"], g["albedo"], g["temperature"], lit,
                            np.array([s.direction for s in lights]).reshape(-1, 3),
                            np.array([s.irradiance_w_m2 / SUN_IRRADIANCE_W_M2 for s in lights]),
                            o.rho_s, o.k_phong, o.ambient, out["range"], out["visible"], out["thermal"], out["x"],
                            out["y"])
        out["z"] = origin[2] + out["range"] * dirs[:, 2]
        shape = (cam.model.height, cam.model.width)
        return {k: v.reshape(shape) for k, v in out.items()}

    def render_reference(self, cam: DescentCamera, R_wb, p_wb) -> dict[str, np.ndarray]:
        """:meth:`render` in numpy after the ray cast (any BRDF): the reference of the fused kernel."""
        dirs, origin, t = self.cast(cam, R_wb, p_wb)
        ok = np.isfinite(t)
        tt = t[ok]
        d = dirs[ok]
        xs = origin[0] + tt * d[:, 0]
        ys = origin[1] + tt * d[:, 1]
        n = np.stack([self.sample("nx", xs, ys), self.sample("ny", xs, ys), self.sample("nz", xs, ys)], axis=-1)
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        albedo = self.sample("albedo", xs, ys)
        lit = {k: self.sample(f"lit:{k}", xs, ys) for k in self.lit}
        shape = (cam.model.height, cam.model.width)
        out = {k: np.full(t.shape, np.nan) for k in ("visible", "thermal", "x", "y", "z")}
        out["visible"][ok] = self.shade_visible(n, -d, albedo, lit)
        out["thermal"][ok] = self.sample("temperature", xs, ys)
        out["x"][ok], out["y"][ok] = xs, ys
        out["z"][ok] = origin[2] + tt * d[:, 2]
        out["range"] = t
        return {k: v.reshape(shape) for k, v in out.items()}
