"""Host side of ``make image-smoke``: drives a render service running in the image over HTTP.

Standard library only (it runs with the host's python3, outside any venv)::

    python3 scripts/image_smoke_client.py --url http://127.0.0.1:18080 --token-file T --dem DEM.tif --out DIR

Checks, in order: ``/healthz`` answers without the token and reports a worker; the API refuses a request
without the token (401); the DEM uploads (201); a small database job (9 tiles) runs to ``done``; its
result downloads, matches the announced SHA-256 and size, and every file of its ``MANIFEST.sha256``
matches.  Exits 1 with the reason on the first failure.
"""
from __future__ import annotations

import argparse
import hashlib
import io
import json
import sys
import time
import urllib.error
import urllib.request
import uuid
import zipfile
from pathlib import Path

#: 40 m at 4 m: 11 x 11 positions in tiles of 4 -> 3 x 3 = 9 tiles, 36 azimuths
JOB = {"kind": "skyline_db", "size_m": 40, "step_m": 4, "azimuths": 36, "tile_size": 4, "camera_height_m": 1.5}


class SmokeError(Exception):
    """A check failed (the message says which and what came back)."""


def request(url: str, *, token: str | None = None, data: bytes | None = None, headers: dict | None = None,
            method: str | None = None, timeout: float = 30.0) -> tuple[int, dict, bytes]:
    req = urllib.request.Request(url, data=data, method=method, headers=dict(headers or {}))
    if token is not None:
        req.add_header("Authorization", f"Bearer {token}")
    try:
        with urllib.request.urlopen(req, timeout=timeout) as r:
            return r.status, dict(r.headers), r.read()
    except urllib.error.HTTPError as e:
        return e.code, dict(e.headers), e.read()


def multipart(field: str, path: Path) -> tuple[bytes, str]:
    boundary = uuid.uuid4().hex
    head = (f"--{boundary}\r\nContent-Disposition: form-data; name=\"{field}\"; filename=\"{path.name}\"\r\n"
            "Content-Type: application/octet-stream\r\n\r\n").encode()
    body = head + path.read_bytes() + f"\r\n--{boundary}--\r\n".encode()
    return body, f"multipart/form-data; boundary={boundary}"


def say(msg: str) -> None:
    sys.stderr.write(f"image-smoke: {msg}\n")
    sys.stderr.flush()


def check(cond: bool, what: str) -> None:
    if not cond:
        raise SmokeError(what)


def wait_healthy(url: str, timeout_s: float) -> dict:
    t_end = time.monotonic() + timeout_s
    last = "no answer"
    while time.monotonic() < t_end:
        try:
            status, _, body = request(url + "/healthz", timeout=5)
            if status == 200:
                health = json.loads(body)
                if health.get("status") == "ok" and (health.get("workers") or 0) >= 1:
                    return health
                last = f"{status} {health}"
        except OSError as exc:
            last = str(exc)
        time.sleep(1)
    raise SmokeError(f"/healthz not ok with a worker after {timeout_s:.0f} s: {last}")


def run(url: str, token: str, dem: Path, out: Path, *, timeout_s: float) -> dict:
    t0 = time.monotonic()
    health = wait_healthy(url, timeout_s)
    say(f"/healthz without a token: {health}")
    status, _, _ = request(url + "/v1/jobs")
    check(status == 401, f"GET /v1/jobs without the token answered {status}, not 401")
    status, _, _ = request(url + "/v1/jobs", token="not-the-token-0123456789")
    check(status == 401, f"GET /v1/jobs with a wrong token answered {status}, not 401")

    body, ctype = multipart("file", dem)
    status, _, resp = request(url + "/v1/dems", token=token, data=body, headers={"Content-Type": ctype})
    check(status == 201, f"DEM upload answered {status}: {resp[:500]!r}")
    dem_rec = json.loads(resp)
    spec = {**JOB, "dem_id": dem_rec["id"], "center": dem_rec["center"]}
    status, _, resp = request(url + "/v1/jobs", token=token, data=json.dumps(spec).encode(),
                              headers={"Content-Type": "application/json"})
    check(status == 202, f"job submission answered {status}: {resp[:500]!r}")
    job_id = json.loads(resp)["id"]
    say(f"DEM {dem_rec['id']} uploaded, job {job_id} submitted")

    t_end = time.monotonic() + timeout_s
    while True:
        status, _, resp = request(f"{url}/v1/jobs/{job_id}", token=token)
        check(status == 200, f"job status answered {status}")
        job = json.loads(resp)
        if job["state"] in ("done", "failed", "cancelled"):
            break
        check(time.monotonic() < t_end, f"job still {job['state']} after {timeout_s:.0f} s: {job}")
        time.sleep(1)
    check(job["state"] == "done", f"job ended {job['state']}: {job.get('error')}")
    check(job["tiles_done"] == job["tiles_total"] == 9, f"tiles {job['tiles_done']}/{job['tiles_total']}, not 9/9")

    status, headers, data = request(f"{url}/v1/jobs/{job_id}/result", token=token, timeout=120)
    check(status == 200, f"result download answered {status}")
    sha = hashlib.sha256(data).hexdigest()
    check(sha == job["result_sha256"] and len(data) == job["result_bytes"],
          f"result {sha} ({len(data)} B) is not the announced {job['result_sha256']} ({job['result_bytes']} B)")
    out.mkdir(parents=True, exist_ok=True)
    (out / "result.zip").write_bytes(data)
    with zipfile.ZipFile(io.BytesIO(data)) as zf:
        manifest = zf.read("MANIFEST.sha256").decode().splitlines()
        check(len(manifest) > 0, "empty MANIFEST.sha256")
        for line in manifest:
            digest, name = line.split("  ", 1)
            check(hashlib.sha256(zf.read(name)).hexdigest() == digest, f"{name} does not match its manifest line")
        names = set(zf.namelist())
    check("db.zarr/zarr.json" in names, "the result holds no db.zarr/zarr.json")
    summary = {"job": job_id, "tiles": job["tiles_total"], "result_bytes": len(data), "files": len(manifest),
               "seconds": round(time.monotonic() - t0, 1)}
    say(f"result downloaded and verified: {summary}")
    return summary


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--url", required=True)
    ap.add_argument("--token-file", required=True, type=Path)
    ap.add_argument("--dem", required=True, type=Path)
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--timeout", type=float, default=300.0, help="seconds for start-up and for the job")
    a = ap.parse_args(argv)
    try:
        run(a.url.rstrip("/"), a.token_file.read_text().strip(), a.dem, a.out, timeout_s=a.timeout)
    except SmokeError as exc:
        sys.stderr.write(f"image-smoke: FAILED: {exc}\n")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
