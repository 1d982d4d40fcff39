import os

import pytest

os.environ.setdefault("MUJOCO_GL", "egl")


@pytest.fixture(scope="session", autouse=True)
def _compiled_kernels():
    """Fill numba's on-disk cache once, as ``twin warmup`` does after an install.

    The command-line tests read stderr line by line; on a fresh checkout the first subprocess
    that builds a mesh index would otherwise also print the first-run compile notice.
    """
    import numpy as np
    import trimesh

    from algorithms.geometry.bvh_kernels import compile_kernels
    from algorithms.registration import localize

    compile_kernels(announce=False)
    sphere = trimesh.creation.icosphere(subdivisions=1, radius=0.05)
    localize(np.asarray(sphere.vertices) + 1e-4, sphere, outlier=None)
