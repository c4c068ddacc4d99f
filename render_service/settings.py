"""Render-service settings (pydantic-settings): environment variables ``SKYLOC_*`` or keywords.

Every limit is enforced by the API before any work starts; sizes are bytes, lengths metres.
"""
from __future__ import annotations

from pathlib import Path

from pydantic import Field, SecretStr
from pydantic_settings import BaseSettings, SettingsConfigDict


class ServiceSettings(BaseSettings):
    """Configuration of one render-service instance.

    Read from the environment with the ``SKYLOC_`` prefix (``SKYLOC_TOKEN``, ``SKYLOC_DATA_DIR``...),
    overridden by keyword arguments (the ``skyloc serve`` options).
    """

    model_config = SettingsConfigDict(env_prefix="SKYLOC_", extra="ignore")

    data_dir: Path = Field(Path("skyloc-data"), description="Folder holding the job store, DEMs, jobs and results")
    host: str = Field("127.0.0.1", description="Interface the server listens on")
    port: int = Field(8000, ge=0, le=65535)
    token: SecretStr | None = Field(None, description="Bearer token (SKYLOC_TOKEN); never logged")
    token_file: Path | None = Field(None, description="File whose first line is the bearer token")
    scheduler: str | None = Field(None, description="Dask scheduler address (tls://host:8786); None: a TLS "
                                                    "LocalCluster with credentials generated in DATA/.dask-tls")
    tls_ca_file: Path | None = Field(None, description="CA certificate (PEM) of the --scheduler's cluster")
    tls_cert: Path | None = Field(None, description="Client certificate (PEM) for the --scheduler")
    tls_key: Path | None = Field(None, description="Client key (PEM) for the --scheduler (else in tls_cert)")
    dashboard: str | None = Field(None, description="Serve the LocalCluster's Dask dashboard on this loopback "
                                                    "host:port (none by default)")
    n_workers: int = Field(2, ge=1, le=256, description="LocalCluster worker processes")
    threads_per_worker: int = Field(1, ge=1, le=64, description="Threads per worker (1: Blender tiles need it)")
    max_upload_bytes: int = Field(512 * 1024**2, ge=1, description="Largest accepted DEM upload, bytes")
    max_dem_pixels: int = Field(1_000_000_000, ge=1, description="Largest accepted DEM raster, columns x rows")
    max_positions: int = Field(4_000_000, ge=1, description="Most grid positions in one database job")
    max_azimuths: int = Field(3600, ge=1, description="Most azimuth samples per skyline")
    max_area_km2: float = Field(100.0, gt=0, description="Largest search area of one job, km^2")
    max_tile_retries: int = Field(2, ge=0, le=20, description="Retries of a failed tile before the job fails")
    max_in_flight_per_worker: int = Field(2, ge=1, le=64, description="Tiles queued on Dask per worker")
    min_free_bytes: int = Field(64 * 1024**2, ge=0, description="Free space the data directory needs for jobs "
                                                                "to start, bytes (less: /healthz degraded)")
    gdal_cache_bytes: int = Field(64 * 1024**2, ge=1024**2, description="GDAL block cache of the API process, "
                                                                        "bytes (bounds DEM validation memory)")
    cors_origins: list[str] = Field(default_factory=list, description="Allowed CORS origins (none by default)")
    scenes_dir: Path = Field(Path(__file__).resolve().parents[1] / "scenes",
                             description="Folder of the scene definitions dataset jobs may name")
    start_cluster: bool = Field(True, description="Start Dask and the job runner (False: API only, for unit tests)")

    @property
    def store_path(self) -> Path:
        return self.data_dir / "skyloc.sqlite"

    @property
    def dems_dir(self) -> Path:
        return self.data_dir / "dems"

    @property
    def jobs_dir(self) -> Path:
        return self.data_dir / "jobs"
