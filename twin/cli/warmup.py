"""``twin warmup``: compile the closest-point and localization kernels now, once per installation.

numba compiles the kernels behind every closest-point query (localization, the global
search, the scan's evaluation) on their first call and keeps them in its on-disk cache, so
the first command of a fresh installation pays the compilation once, and says so on stderr
("compiling closest-point kernels, first run only"). ``twin warmup`` pays it at a moment the
user chooses (after ``pip install``, in a container build). Running it again only loads the
cache. Prints one line on stdout: whether the kernels were compiled or loaded, and the time.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from algorithms.geometry.bvh_kernels import HAVE_NUMBA, compile_kernels, kernels_cached
from twin.cli import COMMANDS


def add_parser(sub) -> None:
    p = sub.add_parser(
        "warmup", help=COMMANDS["warmup"],
        description="Compile the numba closest-point kernels into numba's on-disk cache, so that "
                    "the first twin localize or twin demo starts at once. Again: loads the cache.",
    )
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    if not HAVE_NUMBA:
        result = {"kernels": "numpy backend (numba not installed): nothing to compile", "seconds": 0.0}
    else:
        import time

        import trimesh

        from algorithms.registration import localize

        t0 = time.perf_counter()
        cached = kernels_cached()
        compile_kernels(announce=True)
        # one small localization: compiles (or loads) the kernels of the pose update too
        sphere = trimesh.creation.icosphere(subdivisions=1, radius=0.05)
        localize(np.asarray(sphere.vertices) + 1e-4, sphere, outlier=None)
        seconds = time.perf_counter() - t0
        what = "loaded from the cache" if cached else "compiled"
        result = {"kernels": what, "seconds": round(seconds, 2)}
    if args.json:
        print(json.dumps(result))
    else:
        print(f"closest-point kernels {result['kernels']} in {result['seconds']:.1f} s")
    return 0
