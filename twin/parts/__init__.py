"""Procedural workpieces and mesh loading."""

from twin.parts.workpieces import *  # noqa: F401,F403
from twin.parts.workpieces import MESH_EXTENSIONS, WORKPIECE_NAMES, load_mesh, make_workpiece
