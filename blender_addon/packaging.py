"""Build the Blender extension zip (bpy-free): ``python -m blender_addon.packaging --out DIR``.

The zip holds the extension layer (``__init__``, manifest, props, ops, ui, bridge) at its root.
With ``--wheel`` the skyloc wheel (blender_addon, board: the bpy-free logic) is built into
``wheels/`` and listed in the manifest, as Blender extensions bundle their Python dependencies;
without it the extension expects ``skyloc`` importable (e.g. Blender's Python, or the bpy module
in skyloc's venv).
"""
from __future__ import annotations

import argparse
import logging
import re
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

log = logging.getLogger(__name__)

HERE = Path(__file__).resolve().parent
EXTENSION_FILES = ("__init__.py", "blender_manifest.toml", "props.py", "ui.py", "bridge.py")
EXTENSION_DIRS = ("ops",)


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
        tmp = Path(tempfile.mkdtemp(prefix="skyloc-wheel-"))
        subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-w", str(tmp),
                        str(HERE.parent)], check=True, capture_output=True)
        wheels = sorted(tmp.glob("skyloc-*.whl"))
        manifest = re.sub(r"^wheels\s*=.*$", "wheels = [" + ", ".join(f'"./wheels/{w.name}"' for w in wheels) + "]",
                          manifest, flags=re.M)
    path = out / f"{manifest_id()}-{version}.zip"
    tmp_zip = path.with_suffix(".zip.tmp")
    with zipfile.ZipFile(tmp_zip, "w", zipfile.ZIP_DEFLATED) as z:
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
    tmp_zip.replace(path)
    return path


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="dist", help="output folder")
    ap.add_argument("--wheel", action="store_true", help="bundle the skyloc wheel")
    args = ap.parse_args(argv)
    sys.stdout.write(f"{build_extension(args.out, wheel=args.wheel)}\n")


if __name__ == "__main__":
    main()
