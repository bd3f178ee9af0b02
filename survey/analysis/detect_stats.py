"""Probability of detection (POD) from the detectability study's scores.

Two estimates of the smallest deformation detected with probability ``POD_TARGET``
(MIL-HDBK-1823A, 2009): ``detection_limit`` from hit/miss data (the detected share of
the targets of each tested magnitude, without a model) and ``ahat_a95`` from the
"a-hat versus a" regression of measured on true displacement. Both are defined in the
notes of ``survey.analysis.detectability``, which uses and re-exports them.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from survey.errors import StudyError

__all__ = ["POD_TARGET", "ahat_a95", "detection_limit"]

#: Detection probability the study asks for.
POD_TARGET = 0.95


def detection_limit(magnitudes_m: ArrayLike, shares: ArrayLike,
                    target: float = POD_TARGET) -> float:
    """The smallest magnitude (m) whose detection share, and that of every larger
    magnitude, is >= ``target``; NaN when the largest is not (or a share is NaN)."""
    m = np.asarray(magnitudes_m, dtype=np.float64)
    p = np.asarray(shares, dtype=np.float64)
    order = np.argsort(m)
    m, p = m[order], p[order]
    ok = p >= target             # NaN compares False
    if not ok.size or not ok[-1]:
        return float("nan")
    first = len(ok) - int(np.argmin(ok[::-1])) if not ok.all() else 0
    return float(m[first])


def ahat_a95(a: ArrayLike, d: ArrayLike, lod: ArrayLike, pod: float = POD_TARGET
             ) -> dict[str, float]:
    """The a-hat versus a model (MIL-HDBK-1823A, 2009): least squares
    d = b0 + b1 a over (a, d) pairs (n,), tau the residual standard deviation (ddof 2),
    the decision threshold LoD the median of ``lod`` (k,) (the LoD95 where targets
    are scored); ``a_pod`` = (LoD + z tau - b0) / b1 with z the ``pod`` normal
    quantile (NaN without two distinct a, or with b1 <= 0). Returns {a_pod, b0, b1,
    tau, lod} in m."""
    from scipy.stats import norm

    a, d = (np.asarray(x, dtype=np.float64).ravel() for x in (a, d))
    if a.shape != d.shape:
        raise StudyError(f"Expected `a` and `d` of one length, got {a.size} and {d.size}.")
    lod = np.asarray(lod, dtype=np.float64).ravel()
    lod = lod[np.isfinite(lod)]
    ok = np.isfinite(a) & np.isfinite(d)
    a, d = a[ok], d[ok]
    nan = float("nan")
    if len(a) < 3 or np.ptp(a) <= 0 or not lod.size:
        return {"a_pod": nan, "b0": nan, "b1": nan, "tau": nan, "lod": nan}
    x = np.stack([np.ones_like(a), a], axis=1)
    (b0, b1), *_ = np.linalg.lstsq(x, d, rcond=None)
    res = d - (b0 + b1 * a)
    tau = float(np.sqrt(res @ res / (len(a) - 2)))
    lv = float(np.median(lod))
    z = float(norm.ppf(pod))
    ap = (lv + z * tau - b0) / b1 if b1 > 0 else nan
    return {"a_pod": float(ap), "b0": float(b0), "b1": float(b1), "tau": tau, "lod": lv}
