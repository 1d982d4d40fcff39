"""The adaptive Monte Carlo procedure of JCGM 101:2008 (GUM Supplement 1), section 7.9.

Trials run in batches of ``h`` per cell. After each batch (from the second on), for every
quantity of the cell (each pose-error component where the points fix all six directions, else
the rotation and translation errors), the batches so far give ``h_b`` values each of the
average ``y``, the standard deviation ``u`` and the endpoints ``y_low``, ``y_high`` of the 95 %
probabilistically symmetric coverage interval (7.9.4 b-c). With ``s_q`` the standard
deviation of the average of the ``h_b`` values of ``q`` (``std(q^(r)) / sqrt(h_b)``), the
results are stable when ``2 s_q <= delta`` for all four (7.9.4 e-g), where the numerical
tolerance ``delta`` is half a unit of the last of the ``digits`` significant digits of ``u``
(7.9.2: ``u = c 10^l`` with ``c`` a ``digits``-digit integer, ``delta = 10^l / 2``).

Only trials with status ``ok`` count; a batch with fewer than two of them gives no values, and
a cell is never stable before two batches have values.
"""

from __future__ import annotations

import math

import numpy as np


def numerical_tolerance(u: float, digits: int) -> float:
    """Half a unit in the last of ``digits`` significant digits of ``u`` (JCGM 101, 7.9.2)."""
    if not (math.isfinite(u) and u > 0):
        return 0.0
    exponent = math.floor(math.log10(u)) - digits + 1
    if round(u / 10.0**exponent) >= 10**digits:  # 0.998 with one digit is 1 x 10^0, not 9 x 10^-1
        exponent += 1
    return 0.5 * 10.0**exponent


def batch_values(x: np.ndarray) -> np.ndarray:
    """(average, standard deviation, 2.5 % and 97.5 % percentiles) of one batch's values."""
    lo, hi = np.percentile(x, [2.5, 97.5])
    return np.array([np.mean(x), np.std(x, ddof=1), lo, hi])


def is_stable(batches: list[np.ndarray], digits: int) -> bool:
    """Whether the batches of one quantity (each (n,) values) meet 7.9.4's condition."""
    values = np.array([batch_values(b) for b in batches if len(b) >= 2])
    if len(values) < 2:
        return False
    u = float(np.std(np.concatenate([b for b in batches if len(b) >= 2]), ddof=1))
    delta = numerical_tolerance(u, digits)
    s = np.std(values, axis=0, ddof=1) / math.sqrt(len(values))
    return bool(np.all(2.0 * s <= delta))
