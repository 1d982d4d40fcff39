"""Array type aliases for the public signatures of :mod:`algorithms`.

Shapes, frames and units are stated in each docstring (``points: (N, 3) [m], robot base
frame``); these aliases say the element type only.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]   # float64 array of any shape
IntArray = NDArray[np.int64]       # int64 indices or labels
BoolArray = NDArray[np.bool_]      # masks
Pose = NDArray[np.float64]         # (4, 4) homogeneous transform T_a_b

__all__ = ["ArrayLike", "BoolArray", "FloatArray", "IntArray", "Pose"]
