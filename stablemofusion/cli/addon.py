"""`smf addon --out stablemofusion_addon.zip`: the Blender add-on, ready for Blender's Preferences > Add-ons >
Install. The zip holds the add-on (stablemofusion/assets/blender_addon) with the package's own retargeting
math (motion/rig.py, numpy only) and joint maps, so it works in a Blender whose Python lacks the package."""

from __future__ import annotations

import argparse
from pathlib import Path

ADDON_NAME = "stablemofusion_addon"  # the module name Blender enables


def add_parser(sub, name: str) -> None:
    p = sub.add_parser(name,
                       description="Write the Blender add-on (a panel with prompt, seconds and seed that puts a "
                                   "generated motion on the selected armature) as a zip; docs/character.md.")
    p.add_argument("--out", type=Path, default=Path(f"{ADDON_NAME}.zip"), help=f"zip to write (default {ADDON_NAME}.zip)")
    p.set_defaults(func=run)


def addon_files() -> dict[str, bytes]:
    """Archive name -> bytes of every file of the add-on."""
    from importlib import resources

    pkg = resources.files("stablemofusion")
    files = {f"{ADDON_NAME}/{f.name}": f.read_bytes() for f in (pkg / "assets" / "blender_addon").iterdir()
             if f.name.endswith(".py")}
    files[f"{ADDON_NAME}/rig.py"] = (pkg / "motion" / "rig.py").read_bytes()
    for f in (pkg / "assets" / "joint_maps").iterdir():
        if f.name.endswith(".json"):
            files[f"{ADDON_NAME}/joint_maps/{f.name}"] = f.read_bytes()
    return files


def write_addon(out: Path) -> Path:
    import zipfile

    from ..core.errors import SMFError
    from ..core.io import atomic_path

    if out.suffix.lower() != ".zip":
        raise SMFError(f"--out must be a .zip file, got {out}")
    with atomic_path(out) as tmp:
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as z:
            for name, data in sorted(addon_files().items()):
                z.writestr(name, data)
    return out


def run(args: argparse.Namespace) -> None:
    write_addon(args.out)
    print(f"wrote {args.out}: in Blender, Edit > Preferences > Add-ons > Install..., pick it and enable "
          "'Animation: stablemofusion'")
