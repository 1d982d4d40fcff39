"""``twin export-mesh SCENARIO OUT.stl [--force]``: write the scenario's workpiece mesh.

The mesh is the one every command of the scenario uses (:func:`twin.realize.load_workpiece_mesh`:
the generated part, or the user's mesh converted to metres), in the workpiece frame, so that
the file is the CAD model ``twin localize --model`` takes for points scanned in that scenario.
The format follows the suffix (binary STL, binary PLY, OBJ text; STL and PLY store float32).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import tempfile
from pathlib import Path

import numpy as np

from twin.cli import COMMANDS
from twin.cli.common import add_print_options, print_result
from twin.errors import TwinError
from twin.io.output import PARTIAL_MARK, check_output_file, new_file_mode, raise_if_interrupted
from twin.realize import load_workpiece_mesh
from twin.scenario import load_scenario

#: trimesh's keyword arguments per format: OBJ with every digit of a float64 and faces only
#: (the project's strict reader takes vertices and faces; normals would be recomputed anyway).
EXPORT_OPTIONS: dict[str, dict] = {".stl": {}, ".ply": {}, ".obj": {"include_normals": False,
                                                                    "include_texture": False, "digits": 17}}
FORMAT_NAMES = {".stl": "binary STL", ".ply": "binary PLY", ".obj": "OBJ"}

#: The formats OUT can have (STEP parts are read, not written).
WRITTEN_EXTENSIONS = (".stl", ".obj", ".ply")


def add_parser(sub) -> None:
    p = sub.add_parser(
        "export-mesh", help=COMMANDS["export-mesh"],
        description="Write the workpiece mesh of a scenario (its generated part, or its own mesh converted to "
                    "metres), in the workpiece frame, to OUT: binary STL, binary PLY or OBJ by OUT's suffix. "
                    "The file appears whole (written beside it, then moved into place); an existing file "
                    "is refused unless --force. Prints the path, the triangle count and the bounds.",
    )
    p.add_argument("scenario", help="scenario TOML file")
    p.add_argument("out", metavar="OUT", help=f"mesh file to write ({', '.join(WRITTEN_EXTENSIONS)})")
    p.add_argument("--force", action="store_true", help="replace an existing OUT")
    add_print_options(p, quiet=False)
    p.set_defaults(run=run)


def check_out(path: str, force: bool) -> Path:
    """OUT, refused in one line for a suffix no mesh format has, or an existing file without ``force``."""
    suffix = Path(path).suffix.lower()
    if suffix not in WRITTEN_EXTENSIONS:
        raise TwinError(f"OUT must end in {', '.join(WRITTEN_EXTENSIONS)} (the format follows the suffix), "
                        f"got {path!r}")
    return check_output_file(path, suffix, force, "OUT")


def write_mesh_atomically(mesh, out: Path) -> None:
    """Write ``mesh`` to a hidden temporary file beside ``out``, then move it into place: a file under
    ``out``'s name is always whole, and an error or an interrupt leaves no temporary behind."""
    suffix = out.suffix.lower()
    out.absolute().parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(prefix=f".{out.stem}{PARTIAL_MARK}", suffix=suffix, dir=out.absolute().parent)
    tmp = Path(name)
    try:
        # mkstemp makes the file private (0600); the mesh gets a new file's usual permissions
        os.fchmod(fd, new_file_mode())
        with os.fdopen(fd, "wb") as fh:
            mesh.export(fh, file_type=suffix[1:], **EXPORT_OPTIONS[suffix])
            fh.flush()
            os.fsync(fh.fileno())
        raise_if_interrupted()
        os.replace(tmp, out)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def run(args: argparse.Namespace) -> int:
    scenario = load_scenario(args.scenario)
    out = check_out(args.out, args.force)
    mesh = load_workpiece_mesh(scenario)
    write_mesh_atomically(mesh, out)
    bounds = np.asarray(mesh.bounds, dtype=np.float64)
    result = {
        "path": str(out),
        "format": FORMAT_NAMES[out.suffix.lower()],
        "triangles": int(len(mesh.faces)),
        "vertices": int(len(mesh.vertices)),
        "bounds_m": bounds.tolist(),
        "frame": "workpiece",
        "units": "m",
        # the part's named CAD features ([path] region_features) and their triangle counts
        "features": {name: int(len(f)) for name, f in mesh.metadata.get("features", {}).items()},
    }
    size = " x ".join(f"{v * 1e3:.6g}" for v in bounds[1] - bounds[0])
    rows = [("wrote", f"{out} ({result['format']}, metres, workpiece frame)"),
            ("triangles", f"{result['triangles']} ({result['vertices']} vertices)"),
            ("bounds", "min [" + ", ".join(f"{v:.6g}" for v in bounds[0]) + "] m, max ["
             + ", ".join(f"{v:.6g}" for v in bounds[1]) + "] m"),
            ("size", f"{size} mm"),
            ("features", ", ".join(result["features"]) or "none (a loaded mesh names none)")]
    print_result(args, result, rows)
    return 0
