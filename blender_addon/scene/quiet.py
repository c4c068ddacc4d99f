"""Keep Blender's native chatter ("Saved: '...png'", "render | ..." timings) off the process's stdout.

Blender's C code writes those lines straight to file descriptor 1, so replacing ``sys.stdout``
does not catch them: :func:`native_stdout_captured` points descriptor 1 at a temporary file for
the duration of a block and puts it back afterwards.  Python logging (on ``sys.stderr``,
descriptor 2) is untouched.  No bpy here.
"""
from __future__ import annotations

import ctypes
import logging
import os
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

log = logging.getLogger(__name__)

_STDOUT_FD = 1


@dataclass
class NativeOutput:
    """What native code wrote on descriptor 1 inside the block (filled when the block ends)."""

    text: str = ""


def _flush_all() -> None:
    """Flush Python's and the C library's stdout buffers, so nothing crosses the redirection."""
    for stream in (sys.stdout, sys.__stdout__):
        try:
            if stream is not None:
                stream.flush()
        except (OSError, ValueError):       # closed or detached stream: nothing to flush
            pass
    try:
        ctypes.CDLL(None).fflush(None)      # every C stdio stream (POSIX; absent on Windows)
    except (OSError, AttributeError, TypeError):
        pass


@contextmanager
def native_stdout_captured() -> Iterator[NativeOutput]:
    """Redirect file descriptor 1 to a temporary file inside the block; restore it on exit, always.

    Yields a :class:`NativeOutput` whose ``text`` holds what was written (so a caller can show it
    when something failed); the lines are also logged at DEBUG.  Everything written to
    descriptor 1 by any thread during the block is diverted, including Python ``print``.
    When descriptor 1 is not open, the block runs without redirection.
    """
    out = NativeOutput()
    _flush_all()
    try:
        saved = os.dup(_STDOUT_FD)
    except OSError:                         # no stdout at all: nothing to silence
        yield out
        return
    sink = tempfile.TemporaryFile(mode="w+b")
    try:
        os.dup2(sink.fileno(), _STDOUT_FD)
        try:
            yield out
        finally:
            _flush_all()
            os.dup2(saved, _STDOUT_FD)
            sink.seek(0)
            out.text = sink.read().decode("utf-8", "replace")
            for line in out.text.splitlines():
                log.debug("blender: %s", line)
    finally:
        os.close(saved)
        sink.close()


__all__ = ["NativeOutput", "native_stdout_captured"]
