"""A user's STEP part (ISO 10303-21: AP203, AP214, AP242) meshed into triangles, in metres.

The B-rep is read and meshed by OpenCASCADE (the ``cascadio`` wheel; trimesh reads its glTF
output): every face tessellated with a chordal deviation of at most
:data:`STEP_CHORD_TOLERANCE_M` from the exact surface, and the units the file states (its
``SI_UNIT``: millimetres, metres, inches, ...) converted to metres. The faces' shared edges
are merged into one closed mesh by :func:`twin.formats.meshes.merge_vertices`.
"""

from __future__ import annotations

import os
import sys
import tempfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from twin.errors import TwinError

#: Every tessellated face lies within this distance of the exact surface [m] (the generated
#: parts' chordal tolerance, twin.parts.kernel.CHORD_TOL_M).
STEP_CHORD_TOLERANCE_M = 1e-5
#: ... and turns by at most this much between neighbouring facets [rad].
STEP_ANGULAR_TOLERANCE_RAD = 0.5
#: OpenCASCADE's session length unit, in which it takes the linear deflection [m].
_OCCT_UNIT_M = 1e-3


@contextmanager
def _quiet_fds():
    """Keep OpenCASCADE's messages (written straight to file descriptors 1 and 2) off the
    command's stdout and stderr; the caller reports failures in its own words."""
    saved = [os.dup(1), os.dup(2)]
    with open(os.devnull, "wb") as null:
        os.dup2(null.fileno(), 1)
        os.dup2(null.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for fd in saved:
                os.close(fd)


def read_step(path: Path, chord_tolerance_m: float = STEP_CHORD_TOLERANCE_M) -> tuple[np.ndarray, np.ndarray]:
    """The triangles of a STEP file's solids and surfaces: (V, 3) vertices [m] and (F, 3) faces,
    each face's edges not yet merged with its neighbours'.

    Raises:
        TwinError: the file does not start as STEP (``ISO-10303-21;``), OpenCASCADE cannot read it,
            it holds no solid or surface to mesh, or ``cascadio`` is not installed.
    """
    with open(path, "rb") as fh:
        head = fh.read(64).lstrip(b"\xef\xbb\xbf").lstrip()
    if not head.startswith(b"ISO-10303-21;"):
        raise TwinError(f"{str(path)!r} is not a STEP file: a STEP file starts with ISO-10303-21;")
    if "cascadio" in sys.modules and sys.modules["cascadio"] is None:
        del sys.modules["cascadio"]  # kept from trimesh's start-up by twin/__init__.py
    try:
        import cascadio
        import trimesh
    except ImportError as exc:  # pragma: no cover - cascadio is a dependency
        raise TwinError(f"reading STEP needs the cascadio package ({exc}): pip install cascadio") from None
    with tempfile.TemporaryDirectory(prefix="twin-step-") as tmp:
        glb = Path(tmp) / "part.glb"
        with _quiet_fds():
            rc = cascadio.step_to_glb(str(path), str(glb), tol_linear=chord_tolerance_m / _OCCT_UNIT_M,
                                      tol_angular=STEP_ANGULAR_TOLERANCE_RAD, tol_relative=False)
        if rc != 0 or not glb.is_file() or glb.stat().st_size == 0:
            raise TwinError(f"STEP file {str(path)!r} could not be read or holds no solid or surface to mesh "
                            "(OpenCASCADE found no shape to transfer)")
        scene = trimesh.load_scene(glb)
        meshes = [g for g in scene.dump() if isinstance(g, trimesh.Trimesh) and len(g.faces)]
    if not meshes:
        raise TwinError(f"STEP file {str(path)!r} holds no solid or surface to mesh")
    vertices, faces, offset = [], [], 0
    for m in meshes:
        vertices.append(np.asarray(m.vertices, dtype=np.float64))
        faces.append(np.asarray(m.faces, dtype=np.int64) + offset)
        offset += len(m.vertices)
    return np.vstack(vertices), np.vstack(faces)
