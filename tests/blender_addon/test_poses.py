"""One pose type per frame of reference (issue 13 point 9), as docs/conventions.md lists them."""
from __future__ import annotations

import ast
import importlib
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def _pose_classes() -> set[str]:
    out = set()
    for pkg in ("board", "blender_addon", "render_service", "skyloc"):
        for f in (REPO / pkg).rglob("*.py"):
            mod = ".".join(f.relative_to(REPO).with_suffix("").parts)
            for node in ast.walk(ast.parse(f.read_text())):
                if isinstance(node, ast.ClassDef) and node.name.endswith("Pose"):
                    out.add(f"{mod}.{node.name}")
    return out


def test_the_simulator_has_one_rover_pose_type():
    """``PanoramaPose`` (the same frame as ``Pose``, only the eye height's source differed) is gone."""
    assert _pose_classes() == {"blender_addon.core.acquire.Pose"}


def test_conventions_page_names_one_existing_type_per_frame():
    text = (REPO / "docs" / "conventions.md").read_text()
    section = text.split("## Poses", 1)[1].split("\n## ", 1)[0]
    rows = [r for r in section.splitlines() if r.startswith("| ") and "---" not in r][1:]
    types = [re.search(r"`([\w.]+)`", r.split("|")[2]).group(1) for r in rows]
    frames = [r.split("|")[1].strip() for r in rows]
    assert len(set(frames)) == len(frames) and len(set(types)) == len(types), rows   # one type per frame
    for t in types:                          # each named type exists (and imports without bpy)
        mod, name = t.rsplit(".", 1)
        assert hasattr(importlib.import_module(mod), name), t
    assert "blender_addon.core.acquire.Pose" in types and not any("PanoramaPose" in t for t in types)
