"""The outputs of a Monte Carlo study as JCGM 101:2008 (GUM Supplement 1) states them.

For each output quantity (a pose-error component, an error magnitude) and its ``M`` values:

- the estimate (the average, 7.6) and its standard uncertainty ``u`` (the standard deviation),
  given to two significant digits, the other values to the same decimal place (7.2.6 and 7.9.2);
- the 95 % coverage intervals: the probabilistically symmetric one and the shortest one, both
  read from the sorted values as 7.7.1 and 7.7.2 define them;
- the Monte Carlo standard error of each of these, from ``h`` batches of the values in trial
  order (the standard deviation of the ``h`` batch results over ``sqrt(h)``, as 7.9.4 computes
  it for the adaptive procedure), and whether twice each is within the numerical tolerance of
  ``u``'s two digits (the values are then stable to the digits shown).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from twin.studies.adaptive import numerical_tolerance

COVERAGE = 0.95
#: Significant digits of the standard uncertainty.
DIGITS = 2
#: Batches for the Monte Carlo standard errors, each of at least ``MIN_BATCH`` values (a batch of
#: fewer than 20 has no 95 % interval of its own: 7.7.1 needs q = 0.95 M rounded below M).
BATCHES = 10
MIN_BATCH = 20
#: Below this many trials a cell's coverage intervals are indicative (JCGM 101, 7.2: M >= 10^4
#: for a 95 % interval to about two digits; fewer than 100 values cannot place its ends).
INDICATIVE_BELOW = 100


def _q(m: int, p: float) -> int:
    """The number of values a ``p`` coverage interval spans (JCGM 101, 7.7.1: pM, or the integer
    part of pM + 1/2)."""
    pm = p * m
    return int(pm) if float(pm).is_integer() else int(pm + 0.5)


def symmetric_interval(y: np.ndarray, p: float = COVERAGE) -> tuple[float, float]:
    """The probabilistically symmetric ``p`` coverage interval of the values (JCGM 101, 7.7.1)."""
    s = np.sort(np.asarray(y, dtype=np.float64))
    m = len(s)
    q = _q(m, p)
    if m < 2 or q >= m:
        return float("nan"), float("nan")
    r = (m - q) // 2 if (m - q) % 2 == 0 else (m - q + 1) // 2  # 1-based
    return float(s[r - 1]), float(s[r - 1 + q])


def shortest_interval(y: np.ndarray, p: float = COVERAGE) -> tuple[float, float]:
    """The shortest ``p`` coverage interval of the values (JCGM 101, 7.7.2)."""
    s = np.sort(np.asarray(y, dtype=np.float64))
    m = len(s)
    q = _q(m, p)
    if m < 2 or q >= m:
        return float("nan"), float("nan")
    widths = s[q:] - s[: m - q]
    r = int(np.argmin(widths))
    return float(s[r]), float(s[r + q])


def _results(y: np.ndarray) -> np.ndarray:
    """(estimate, u, symmetric low, symmetric high, shortest low, shortest high) of the values."""
    mean = float(np.mean(y)) if len(y) else float("nan")
    u = float(np.std(y, ddof=1)) if len(y) > 1 else float("nan")
    return np.array([mean, u, *symmetric_interval(y), *shortest_interval(y)])


@dataclass(frozen=True)
class Output:
    """One output quantity of a cell: :func:`summarize`'s result.

    Attributes:
        n: the values used.
        values: (6,) estimate, u, symmetric low and high, shortest low and high.
        mc_se: (6,) their Monte Carlo standard errors (NaN: too few values for batches).
        tolerance: the numerical tolerance of ``u``'s two significant digits.
    """

    n: int
    values: np.ndarray
    mc_se: np.ndarray
    tolerance: float

    @property
    def stable(self) -> bool:
        """Twice every Monte Carlo standard error within the numerical tolerance (JCGM 101, 7.9.4)."""
        return bool(np.all(np.isfinite(self.mc_se)) and np.all(2.0 * self.mc_se <= self.tolerance))

    @property
    def indicative(self) -> bool:
        return self.n < INDICATIVE_BELOW


def summarize(y: np.ndarray) -> Output:
    """The JCGM 101 outputs of one quantity's values (in trial order)."""
    y = np.asarray(y, dtype=np.float64)
    y = y[np.isfinite(y)]
    values = _results(y)
    h = min(BATCHES, len(y) // MIN_BATCH)
    if h >= 2:
        batches = np.array([_results(b) for b in np.array_split(y, h)])
        mc_se = np.std(batches, axis=0, ddof=1) / math.sqrt(h)
    else:
        mc_se = np.full(6, np.nan)
    return Output(len(y), values, mc_se, numerical_tolerance(values[1], DIGITS))


def decimals(u: float, digits: int = DIGITS) -> int:
    """The decimal places that give ``u`` to ``digits`` significant digits (0 or more)."""
    if not (math.isfinite(u) and u > 0):
        return 3
    return max(0, digits - 1 - math.floor(math.log10(u)))


def fmt(value: float, places: int) -> str:
    """``value`` rounded to ``places`` decimals ("n/a" when not finite; no sign on a zero)."""
    if not math.isfinite(value):
        return "n/a"
    text = f"{value:.{places}f}"
    return text[1:] if text.startswith("-") and float(text) == 0.0 else text


def fmt_se(value: float) -> str:
    """A Monte Carlo standard error to two significant digits."""
    return "n/a" if not math.isfinite(value) else f"{value:.2g}"
