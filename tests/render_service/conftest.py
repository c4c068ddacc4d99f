"""The DEM the render-service tests upload: the real HiRISE Gale patch when ../shared/data/dems has it,
else a procedural Mars GeoTIFF, so that the service (API, queue, resume, cancel, result, auth, limits,
schema) is tested on a clean clone too.

Both are Mars, 1 m cells, in a projected (metric) equirectangular CRS, and large enough for the jobs
the tests submit (grids up to 300 m a side around the DEM's centre); the tests assert nothing that
only one of them has (sizes, bounds and body are read from the upload or from GDAL).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import pytest

log = logging.getLogger(__name__)

GALE = "mars_gale_hirise_1m_mmgis_missionDEM.tif"  # 348 x 337 cells of 1 m, 470 kB
# procedural fallback: 400 m x 400 m at 1 m (160 000 cells, about 450 kB), byte-reproducible
FALLBACK = {"preset": "mars", "size_m": 400.0, "res_m": 1.0, "seed": 7}


@dataclass(frozen=True)
class ServiceDem:
    """A DEM file for the service tests: ``path``, its ``body`` and where it came from (``source``)."""

    path: Path
    body: str
    source: str  # "real:<file name>" or "procedural"

    @property
    def is_real(self) -> bool:
        return self.source.startswith("real:")


@pytest.fixture(scope="session")
def service_dem(optional_real_dem, tmp_path_factory) -> ServiceDem:
    """The real Gale DEM if present, else the procedural Mars DEM of FALLBACK (made once per session)."""
    real = optional_real_dem(GALE)
    if real is not None:
        return ServiceDem(real, "mars", f"real:{GALE}")
    from blender_addon.terrain.procedural import synthesize

    path = synthesize(FALLBACK["preset"], size_m=FALLBACK["size_m"], res_m=FALLBACK["res_m"],
                      seed=FALLBACK["seed"], out_path=tmp_path_factory.mktemp("service_dem") / "mars_procedural.tif")
    log.info("real DEM %s absent: the service tests use the procedural DEM %s", GALE, path)
    return ServiceDem(path, "mars", "procedural")
