"""A tiny HTTP client for the render service (standard library only: it runs inside Blender).

The add-on reaches the service over HTTP, never by import.  Endpoints (see render_service/api):
``POST /v1/dems`` (multipart field ``file``), ``POST /v1/jobs`` (JSON, kind ``skyline_db``),
``GET /v1/jobs/{id}``.
"""
from __future__ import annotations

import json
import logging
import mimetypes
import os
import urllib.error
import urllib.request
import uuid
from pathlib import Path

from board.errors import InvalidInputError, SkylocError

log = logging.getLogger(__name__)


class ServiceError(SkylocError):
    """The render service refused a request or could not be reached."""


def _request(url: str, *, data: bytes | None = None, headers: dict | None = None, method: str = "GET",
             token: str | None = None, timeout: float = 60.0) -> dict:
    h = dict(headers or {})
    if token:
        h["Authorization"] = f"Bearer {token}"
    req = urllib.request.Request(url, data=data, headers=h, method=method)
    try:
        with urllib.request.urlopen(req, timeout=timeout) as resp:
            return json.loads(resp.read().decode("utf-8") or "{}")
    except urllib.error.HTTPError as exc:
        body = exc.read().decode("utf-8", "replace")
        try:
            detail = json.loads(body).get("detail", body)
        except ValueError:
            detail = body
        raise ServiceError(f"{method} {url} failed with HTTP {exc.code}: {detail}") from None
    except urllib.error.URLError as exc:
        raise ServiceError(f"cannot reach the render service at {url}: {exc.reason}; start it with "
                           "`skyloc serve` or fix the service URL") from None


def upload_dem(base_url: str, dem_path: str | os.PathLike, *, body: str | None = None,
               token: str | None = None) -> dict:
    """Upload a DEM file; returns the service's DemOut (``id``, ``center``, ``bounds`` ...)."""
    p = Path(dem_path)
    if not p.is_file():
        raise InvalidInputError(f"DEM file {p} does not exist: give an existing GeoTIFF")
    boundary = uuid.uuid4().hex
    ctype = mimetypes.guess_type(p.name)[0] or "application/octet-stream"
    parts = [f"--{boundary}\r\nContent-Disposition: form-data; name=\"file\"; filename=\"{p.name}\"\r\n"
             f"Content-Type: {ctype}\r\n\r\n".encode(), p.read_bytes(), b"\r\n"]
    if body:
        parts.append(f"--{boundary}\r\nContent-Disposition: form-data; name=\"body\"\r\n\r\n{body}\r\n".encode())
    parts.append(f"--{boundary}--\r\n".encode())
    return _request(base_url.rstrip("/") + "/v1/dems", data=b"".join(parts), method="POST", token=token,
                    headers={"Content-Type": f"multipart/form-data; boundary={boundary}"})


def submit_db_job(base_url: str, *, dem_id: str, center: tuple[float, float], size_m: float, step_m: float,
                  camera_height_m: float = 2.0, azimuths: int = 360, renderer: str = "raymarch",
                  tile_size: int = 64, token: str | None = None) -> dict:
    """Submit a skyline-database job; returns the JobOut (``id``, ``state``, ``tiles_done`` ...)."""
    doc = {"kind": "skyline_db", "dem_id": dem_id, "center": [float(center[0]), float(center[1])],
           "size_m": float(size_m), "step_m": float(step_m), "camera_height_m": float(camera_height_m),
           "azimuths": int(azimuths), "renderer": renderer, "tile_size": int(tile_size)}
    return _request(base_url.rstrip("/") + "/v1/jobs", data=json.dumps(doc).encode(), method="POST", token=token,
                    headers={"Content-Type": "application/json"})


def job_status(base_url: str, job_id: str, *, token: str | None = None) -> dict:
    """The JobOut of a job (``state``: queued, running, done, failed, ...)."""
    return _request(base_url.rstrip("/") + f"/v1/jobs/{job_id}", token=token)


def job_fraction(job: dict) -> float:
    """Progress 0..1 of a JobOut."""
    total = job.get("tiles_total") or 0
    return 1.0 if job.get("state") == "done" else (float(job.get("tiles_done", 0)) / total if total else 0.0)
