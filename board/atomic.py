"""Atomic file writes: write next to the target, then ``os.replace`` (readers see the old file or the new one,
never half of one; a failure leaves the target as it was and removes the temporary file).

The one place for these writers (files: :func:`atomic_path`, :func:`write_text_atomic`,
:func:`write_json_atomic`; folders: :func:`atomic_dir`) and for the file hash every product records
(:func:`file_sha256`)."""
from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, *, suffix: str = ".part") -> Iterator[Path]:
    """Yield a temporary path next to ``path`` (its name + the process id + ``suffix``) to write; replace
    ``path`` with it on success.  ``suffix`` may end with the format's extension when a writer infers the format from it
    (matplotlib, GDAL): ``suffix=".part.png"``."""
    path = Path(path)
    tmp = path.with_name(f"{path.name}.{os.getpid()}{suffix}")  # per process: concurrent writers never share one
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def write_text_atomic(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` to ``path`` atomically; returns the path."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return Path(path)


def write_json_atomic(path: str | os.PathLike, doc, *, indent: int | None = 2) -> Path:
    """Write ``doc`` as JSON to ``path`` atomically; returns the path."""
    return write_text_atomic(path, json.dumps(doc, indent=indent))


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike, *, suffix: str = ".part") -> Iterator[Path]:
    """Yield a new empty folder next to ``path`` to fill; on success it replaces ``path`` (an earlier folder there
    is moved aside first and removed after the swap, so ``path`` is always a complete folder or absent); on
    failure the temporary folder is removed and ``path`` is left as it was."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent))
    try:
        yield tmp
        if path.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".old", dir=path.parent))
            os.replace(path, old / path.name)
            os.replace(tmp, path)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, path)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def file_sha256(path: str | os.PathLike, *, chunk: int = 1 << 20) -> str:
    """Hex SHA-256 of a file's bytes, read in ``chunk``-byte blocks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(chunk), b""):
            h.update(block)
    return h.hexdigest()


def publish_dir(tmp: str | os.PathLike, out: str | os.PathLike) -> bool:
    """Rename the finished folder ``tmp`` to ``out`` unless another process published ``out`` first (then
    ``tmp`` is removed): for products any worker may build and the first one wins.  True if published here."""
    tmp, out = Path(tmp), Path(out)
    try:
        os.rename(tmp, out)
        return True
    except OSError:
        shutil.rmtree(tmp, ignore_errors=True)
        if not out.exists():
            raise
        return False
