"""Generated CAD workpieces of the source documents, and loading a user's mesh.

Every generator returns one watertight, consistently wound ``trimesh.Trimesh`` with outward
normals, in the workpiece frame: metres, z up, the part resting on z = 0 (its bottom face lies
in that plane), roughly centred on the origin in x and y. Scenarios name a part by its key in
:data:`WORKPIECE_NAMES` (``workpiece.shape``) and pass its keyword arguments
(``workpiece.params``) through :func:`make_workpiece`.

The source documents give no dimensions for any of these parts; the defaults are plausible
choices documented on each generator.

* ``s_surface`` (:mod:`~twin.parts.s_surface`): document 004's S-shaped surface part
  (laser-scanned by the robot).
* ``hemisphere_punch``, ``bottle_punch`` (:mod:`~twin.parts.punches`): document 000's
  workpieces A (hemisphere + plate + four small cylinders) and B (plate + half plastic
  bottle of Bezier patches).
* ``inner_sphere``, ``through_hole`` (:mod:`~twin.parts.cavities`): document 002's "inner
  sphere containing a cylinder" (a spherical cavity opened at the top face of a block, with
  a cylindrical post inside it) and its block with a horizontal through hole.
* ``bore_and_face``, ``sphere``, ``cube``, ``cast_blank``, ``cast_blank_finished``
  (:mod:`~twin.parts.symmetric`): the parts of symmetric and hybrid localization
  (document 000, sections 4 and 5).

Layout: :mod:`~twin.parts.kernel` is the meshing kernel every family builds on (parameter
checks, surfaces of revolution, boxes, assembly), :mod:`~twin.parts.planar` meshes its planar
faces; within the package, each family module imports only these two;
:mod:`~twin.parts.loading` reads mesh files; this module
imports the families and holds the registry (``_GENERATORS``). No module registers itself:
adding a part means adding its generator to a family module and one line to the registry.

Parameter schema: a generator's keyword signature, every argument with a default, is its
schema. :func:`make_workpiece` reads it with :mod:`inspect` to refuse unknown names, and the
generator checks values (types, ranges, and whether the features fit together, with messages
naming the parameters). Parameter dataclasses were considered and not adopted: a scenario's
``params`` table maps directly onto the keywords, the defaults and their documentation
already live in one place (the signature and docstring), and a dataclass per generator
would repeat every name and default without moving any of the cross-parameter checks out of
the generators.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable

import numpy as np
import trimesh

from twin.errors import TwinError
from twin.parts.cavities import inner_sphere, through_hole
from twin.parts.loading import MESH_EXTENSIONS, load_mesh
from twin.parts.punches import bottle_profile_bezier, bottle_punch, hemisphere_punch
from twin.parts.s_surface import s_surface, s_surface_height, s_surface_normal
from twin.parts.symmetric import (
    bore_and_face,
    cast_blank,
    cast_blank_finished,
    cast_blank_geometry,
    cast_blank_rough_points,
    classify_cast_blank_points,
    cube,
    sphere,
)

__all__ = [
    "WORKPIECE_NAMES",
    "MESH_EXTENSIONS",
    "make_workpiece",
    "load_mesh",
    "s_surface",
    "s_surface_height",
    "s_surface_normal",
    "hemisphere_punch",
    "bottle_punch",
    "bottle_profile_bezier",
    "inner_sphere",
    "through_hole",
    "bore_and_face",
    "sphere",
    "cube",
    "cast_blank",
    "cast_blank_finished",
    "cast_blank_geometry",
    "cast_blank_rough_points",
    "classify_cast_blank_points",
]

_GENERATORS: dict[str, Callable[..., trimesh.Trimesh]] = {
    "s_surface": s_surface,
    "hemisphere_punch": hemisphere_punch,
    "bottle_punch": bottle_punch,
    "inner_sphere": inner_sphere,
    "through_hole": through_hole,
    "bore_and_face": bore_and_face,
    "sphere": sphere,
    "cube": cube,
    "cast_blank": cast_blank,
    "cast_blank_finished": cast_blank_finished,
}

WORKPIECE_NAMES: tuple[str, ...] = tuple(_GENERATORS)
"""Names accepted by :func:`make_workpiece`, in the order of the registry."""


def make_workpiece(name: str, **params: object) -> trimesh.Trimesh:
    """Build a named workpiece.

    Args:
        name: one of :data:`WORKPIECE_NAMES`.
        **params: keyword arguments of that generator (all have defaults).

    Returns:
        Watertight mesh [m], workpiece frame, bottom face at z = 0.

    Raises:
        TwinError: unknown name, unknown parameter, or a parameter the generator refuses.
    """
    if not isinstance(name, str) or name not in _GENERATORS:
        raise TwinError(
            f"unknown workpiece {name!r}; valid names are: {', '.join(WORKPIECE_NAMES)}"
        )
    generator = _GENERATORS[name]
    valid = list(inspect.signature(generator).parameters)
    for key in params:
        if key not in valid:
            raise TwinError(
                f"unknown parameter {key!r} for workpiece {name!r}; valid parameters are: "
                f"{', '.join(valid)}"
            )
    try:
        cache_key = (name, tuple(sorted((k, _frozen(v)) for k, v in params.items())))
        hash(cache_key)
    except TypeError:   # a parameter that cannot be a key: built every time
        return generator(**params)
    if cache_key not in _BUILT:
        if len(_BUILT) >= _BUILT_MAX:
            _BUILT.pop(next(iter(_BUILT)))
        _BUILT[cache_key] = generator(**params)
    return _BUILT[cache_key].copy()


#: Parts built in this process, by (name, frozen parameters): a generated part takes 0.1-1.5 s
#: and is the same every time, and a study or a test suite realizes the same part again and
#: again. Callers get a copy; the oldest entry goes first past :data:`_BUILT_MAX`.
_BUILT: dict[tuple, trimesh.Trimesh] = {}
_BUILT_MAX = 32


def _frozen(value: object) -> object:
    """A parameter as a hashable key: lists and arrays as tuples (their values, not identity)."""
    if isinstance(value, (list, tuple, np.ndarray)):
        return tuple(_frozen(v) for v in value)
    if isinstance(value, np.generic):
        return value.item()
    return value
