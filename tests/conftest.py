"""Shared pytest fixtures: the real DEMs in ../shared/data/dems and a sandboxed Blender config."""
from __future__ import annotations

import atexit
import importlib.util
import os
import sys
import shutil
import tempfile
from pathlib import Path

import pytest

_TMP = Path(tempfile.mkdtemp(prefix="skyloc-tests-"))
atexit.register(shutil.rmtree, _TMP, ignore_errors=True)
# Blender writes user config and caches under ~/.config: keep tests hermetic.
os.environ.setdefault("BLENDER_USER_RESOURCES", str(_TMP / "blender"))
os.environ.setdefault("XDG_CACHE_HOME", str(_TMP / "xdg"))

REPO = Path(__file__).resolve().parents[1]
# SKYLOC_TEST_DEMS=<folder> points the real-DEM fixtures elsewhere (an empty folder: run as on a clean clone).
SHARED_DEMS = Path(os.environ.get("SKYLOC_TEST_DEMS") or REPO.parent / "shared" / "data" / "dems")


def _register_service_helpers() -> None:
    """Make tests/render_service/_service_helpers.py importable as ``skyloc_service_test_helpers``
    (tests are collected with --import-mode=importlib, so test folders are not packages)."""
    name = "skyloc_service_test_helpers"
    spec = importlib.util.spec_from_file_location(name, Path(__file__).with_name("render_service") / "_service_helpers.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)


_register_service_helpers()


@pytest.fixture(scope="session")
def dems_dir() -> Path:
    """Folder of the real DEMs; skips the test cleanly when it is absent."""
    if not SHARED_DEMS.is_dir():
        pytest.skip(f"real DEMs not found at {SHARED_DEMS} (the shared/ folder beside the repository)")
    return SHARED_DEMS


@pytest.fixture(scope="session")
def real_dem(dems_dir):
    """Return a function name -> path of a real DEM, skipping when that file is missing."""

    def get(name: str) -> Path:
        p = dems_dir / name
        if not p.is_file():
            pytest.skip(f"real DEM {name} not found in {dems_dir}")
        return p

    return get


@pytest.fixture(scope="session")
def optional_real_dem():
    """Return a function name -> path of a real DEM, or None when it is absent (for tests with a fallback)."""

    def get(name: str) -> Path | None:
        p = SHARED_DEMS / name
        return p if p.is_file() else None

    return get
