"""Import direction (DESIGN.md): board imports nothing of ours; core/terrain never import bpy."""
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _modules(package: str) -> list[str]:
    """Every module of ``package`` (files on disk, sub-packages included)."""
    root = REPO / package.replace(".", "/")
    out = []
    for f in sorted(root.rglob("*.py")):
        parts = list(f.relative_to(REPO).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out.append(".".join(parts))
    return out


def _loaded_after_import(modules: list[str]) -> set[str]:
    code = ("import sys\n" + "".join(f"import {m}\n" for m in modules) +
            "print(' '.join(sorted({n.split('.')[0] for n in sys.modules})))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO)
    assert out.returncode == 0, out.stderr
    return set(out.stdout.split())


def test_board_imports_nothing_else_of_ours():
    top = _loaded_after_import(_modules("board"))
    assert not top & {"blender_addon", "render_service", "skyloc", "bpy", "osgeo", "numba", "dask", "fastapi"}


@pytest.mark.parametrize("package", ["blender_addon.core", "blender_addon.terrain"])
def test_bpy_free_layers_never_import_bpy(package):
    assert "bpy" not in _loaded_after_import(_modules(package))
