"""A job's published result: a zip of its output folder with a ``MANIFEST.sha256``, written atomically."""
from __future__ import annotations

import os
import zipfile
from pathlib import Path

from board.atomic import atomic_path, file_sha256

RESULT_NAME = "result.zip"
MANIFEST_NAME = "MANIFEST.sha256"
_ZIP_EPOCH = (1980, 1, 1, 0, 0, 0)  # fixed entry times: same database, same zip bytes


__all__ = ["MANIFEST_NAME", "RESULT_NAME", "file_sha256", "write_result_zip"]


def write_result_zip(folder: Path, zip_path: Path, *, arcroot: str) -> tuple[str, int]:
    """Zip ``folder`` under ``arcroot/`` with a ``MANIFEST.sha256`` (sha256sum format); atomic.

    Entries are sorted and carry a fixed time, so the same content gives the same zip bytes.
    The temporary ``<zip>.tmp`` is removed when anything fails (a full disk included).
    Returns (sha256 of the zip, size in bytes).
    """
    files = sorted(p for p in folder.rglob("*") if p.is_file())
    manifest = []
    with atomic_path(zip_path, suffix=".tmp") as tmp:  # runner.py sweeps stale "*.tmp" files
        with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_STORED) as zf:
            for p in files:
                arc = f"{arcroot}/{p.relative_to(folder).as_posix()}"
                manifest.append(f"{file_sha256(p)}  {arc}")
                zf.writestr(zipfile.ZipInfo(arc, _ZIP_EPOCH), p.read_bytes())
            zf.writestr(zipfile.ZipInfo(MANIFEST_NAME, _ZIP_EPOCH), "\n".join(manifest) + "\n")
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
    return file_sha256(zip_path), zip_path.stat().st_size
