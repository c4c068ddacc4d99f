"""Build the Blender extension zip (bpy-free): ``python -m blender_addon.packaging --out DIR``.

The zip holds the extension layer (``__init__``, manifest, props, ops, ui, bridge) at its root.
With ``--wheel`` the skyloc wheel (blender_addon, board: the bpy-free logic) and every wheel it
depends on for this platform and Python (``pip download``, binary wheels only) are put into
``wheels/`` and listed in the manifest with its ``platforms``, as Blender extensions bundle their
Python dependencies.  Not bundled: numpy (Blender ships it) and GDAL's ``osgeo`` bindings (not
published as wheels on PyPI; DEM import needs them in Blender's Python, see docs/blender.md).
Without ``--wheel`` the extension expects ``skyloc`` importable (the bpy module in skyloc's venv).

The zip passes Blender's own validator (``bl_pkg/cli/blender_ext.py validate``, shipped with the
bpy module; tests/blender_addon/test_extension.py runs it).
"""
from __future__ import annotations

import argparse
import logging
import platform
import re
import subprocess
import sys
import tempfile
import tomllib
import zipfile
from pathlib import Path

from board.atomic import atomic_path

log = logging.getLogger(__name__)

HERE = Path(__file__).resolve().parent
EXTENSION_FILES = ("__init__.py", "blender_manifest.toml", "props.py", "ui.py", "ui_descent.py", "bridge.py")
EXTENSION_DIRS = ("ops",)
#: distributions Blender already ships: not bundled (a second numpy would shadow Blender's)
PROVIDED_BY_BLENDER = frozenset({"numpy"})


def dist_name(wheel: Path) -> str:
    """Normalised distribution name of a wheel file: "opencv_python_headless-4.11...whl" -> "opencv-python-headless"."""
    return re.sub(r"[-_.]+", "-", wheel.name.split("-")[0]).lower()


def blender_platform() -> str:
    """Blender's name of this platform (``platforms`` in the manifest): linux-x64, macos-arm64, windows-x64..."""
    os_name = {"linux": "linux", "darwin": "macos", "win32": "windows"}.get(sys.platform, sys.platform)
    arch = {"x86_64": "x64", "amd64": "x64", "aarch64": "arm64", "arm64": "arm64"}.get(platform.machine().lower(),
                                                                                     platform.machine().lower())
    return f"{os_name}-{arch}"


def runtime_requirements() -> list[str]:
    """skyloc's base dependencies (pyproject.toml ``[project] dependencies``), minus what Blender ships."""
    doc = tomllib.loads((HERE.parent / "pyproject.toml").read_text())
    reqs = doc["project"]["dependencies"]
    return [r for r in reqs if re.split(r"[<>=!~ ;\[]", r, maxsplit=1)[0].lower() not in PROVIDED_BY_BLENDER]


def build_wheels(dest: Path) -> list[Path]:
    """The skyloc wheel and every binary wheel it needs on this platform and Python, into ``dest``.

    Raises subprocess.CalledProcessError (with pip's output) when a wheel cannot be built or downloaded.
    """
    def pip(*args: str) -> None:
        res = subprocess.run([sys.executable, "-m", "pip", *args], capture_output=True, text=True)
        if res.returncode != 0:
            raise subprocess.CalledProcessError(res.returncode, res.args, res.stdout, res.stderr)

    pip("wheel", "--no-deps", "--no-build-isolation", "-w", str(dest), str(HERE.parent))
    pip("download", "--only-binary=:all:", "-d", str(dest), *runtime_requirements())
    for w in dest.glob("*.whl"):
        if dist_name(w) in PROVIDED_BY_BLENDER:
            w.unlink()
    return sorted(dest.glob("*.whl"))


def manifest_id() -> str:
    """The extension id from blender_manifest.toml (also its module name under ``bl_ext.<repo>``)."""
    m = re.search(r'^id\s*=\s*"([^"]+)"', (HERE / "blender_manifest.toml").read_text(), re.M)
    return m.group(1) if m else "skyloc"


def build_extension(out_dir: str | Path, *, wheel: bool = False) -> Path:
    """Write ``skyloc-<version>.zip`` into ``out_dir`` and return its path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    manifest = (HERE / "blender_manifest.toml").read_text()
    version = re.search(r'^version\s*=\s*"([^"]+)"', manifest, re.M).group(1)
    wheels: list[Path] = []
    if wheel:
        wheels = build_wheels(Path(tempfile.mkdtemp(prefix="skyloc-wheel-")))
        manifest = re.sub(r"^wheels\s*=.*$", "wheels = [" + ", ".join(f'"./wheels/{w.name}"' for w in wheels) + "]",
                          manifest, flags=re.M)
        if any(not w.name.endswith("-none-any.whl") for w in wheels):  # platform wheels: say for which platform
            manifest = manifest.replace('\nlicense =', f'\nplatforms = ["{blender_platform()}"]\nlicense =', 1)
    path = out / f"{manifest_id()}-{version}.zip"
    with atomic_path(path, suffix=".tmp.zip") as tmp_zip, zipfile.ZipFile(tmp_zip, "w", zipfile.ZIP_DEFLATED) as z:
        for name in EXTENSION_FILES:
            if name == "blender_manifest.toml":
                z.writestr(name, manifest)
            else:
                z.write(HERE / name, name)
        for d in EXTENSION_DIRS:
            for f in sorted((HERE / d).glob("*.py")):
                z.write(f, f"{d}/{f.name}")
        for w in wheels:
            z.write(w, f"wheels/{w.name}")
    return path


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="dist", help="output folder")
    ap.add_argument("--wheel", action="store_true", help="bundle the skyloc wheel")
    args = ap.parse_args(argv)
    sys.stdout.write(f"{build_extension(args.out, wheel=args.wheel)}\n")


if __name__ == "__main__":
    main()
