"""The Dask engine started from a process that imported bpy (the demo, a script run inside Blender).

Blender's module puts its ``scripts/modules`` folder (which holds a Blender-only ``bpy`` package) on
``sys.path``; spawned workers inherit the parent's path, so without care every worker fails with
``No module named '_bpy'`` as soon as a task imports bpy.
"""
from __future__ import annotations

import sys

import pytest


def _bpy_version() -> str:
    import bpy  # noqa: PLC0415

    return bpy.app.version_string


@pytest.mark.blender
def test_workers_import_bpy_after_the_parent_did():
    bpy = pytest.importorskip("bpy")
    from render_service.engine import dask_client

    before = list(sys.path)
    with dask_client(None, n_workers=1) as client:
        assert client.submit(_bpy_version, pure=False).result(timeout=120) == bpy.app.version_string
    assert sys.path == before  # the parent's path is given back
