"""Atomic file writes: write next to the target, then ``os.replace`` (readers see the old file or the new one,
never half of one; a failure leaves the target as it was and removes the temporary file)."""
from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Iterator
from pathlib import Path


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, *, suffix: str = ".part") -> Iterator[Path]:
    """Yield a temporary path next to ``path`` (its name + ``suffix``) to write; replace ``path`` with it on
    success.  ``suffix`` may end with the format's extension when a writer infers the format from it
    (matplotlib, GDAL): ``suffix=".part.png"``."""
    path = Path(path)
    tmp = path.with_name(path.name + suffix)
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
