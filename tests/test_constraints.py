"""constraints.txt, the versions a clean clone installs (scripts/install.sh ``pip install -c``), agrees
with pyproject.toml: every dependency and optional dependency is pinned there (nothing a later release
can change under CI) and every pin satisfies the specifier pyproject.toml asks for (a bump of one
without the other is caught here, not by a red CI on a fresh machine).
"""
from __future__ import annotations

import tomllib
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

REPO = Path(__file__).resolve().parents[1]


def _pins() -> dict[str, Version]:
    """constraints.txt as {canonical name: pinned version}; a line that is not ``name==version`` fails."""
    pins: dict[str, Version] = {}
    for n, line in enumerate((REPO / "constraints.txt").read_text().splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        name, sep, version = line.partition("==")
        assert sep and name and version, f"constraints.txt:{n}: {line!r} is not name==version"
        pins[canonicalize_name(name)] = Version(version)
    return pins


def _requirements() -> list[Requirement]:
    """Every requirement of pyproject.toml, the core and each optional group."""
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    lines = list(project["dependencies"])
    for group in project["optional-dependencies"].values():
        lines += group
    return [Requirement(r) for r in lines]


def test_every_dependency_is_pinned_within_its_specifier():
    pins = _pins()
    for req in _requirements():
        name = canonicalize_name(req.name)
        assert name in pins, f"{req.name} is in pyproject.toml but not pinned in constraints.txt: run `make lock`"
        assert req.specifier.contains(pins[name], prereleases=True), (
            f"constraints.txt pins {req.name}=={pins[name]}, outside pyproject.toml's {req}: run `make lock`")


def test_gdal_is_left_to_the_system_library():
    """The GDAL bindings are built against ``gdal-config --version``; a pin would fight it."""
    assert "gdal" not in _pins()
