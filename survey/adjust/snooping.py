"""Baarda's iterative data snooping for Helmert adjustments, and points left out by hand.

Baarda 1968 ("A testing procedure for use in geodetic networks", Netherlands Geodetic
Commission, Publications on Geodesy 2(5)): test every observation with its w-test
(Pope's tau-test when sigma0 is estimated); if the largest exceeds the critical value
(3.29 for alpha0 = 0.001, two-sided standard normal), remove that observation, adjust
again and repeat until no test exceeds it. One blunder raises the tests of its
neighbours too, so only the largest is removed at each step.

Here an observation is a control point (its three coordinates): a point whose largest
coordinate test is the worst is left out as a whole, as a surveyor does with a
disturbed prism.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from survey.adjust.helmert_stats import MODELS
from survey.adjust.helmert import HelmertModel, HelmertResult, fit_helmert, model_name
from survey.errors import HelmertError

__all__ = ["SnoopStep", "Snooping", "data_snooping"]


@dataclass(frozen=True)
class SnoopStep:
    """One step of data snooping: the point removed, its test value and the critical
    value it exceeded (in the adjustment before the step), and the adjustment after it.

    Attributes
    ----------
    removed : str, the id of the point removed
    statistic : float, its test value
    test : "w" or "tau"
    critical : float, the critical value it exceeded
    sigma0_after : float, sigma0 of the adjustment after the step
    points_left : int, points in the adjustment after the step
    above_after : int, points still above the critical value after the step
    """

    removed: str
    statistic: float
    test: str
    critical: float
    sigma0_after: float
    points_left: int
    above_after: int


@dataclass(repr=False)
class Snooping:
    """An adjustment with points left out: by hand (``excluded``) and by data snooping
    (``steps``).

    Attributes
    ----------
    result : HelmertResult, the final adjustment
    initial : HelmertResult, the adjustment before snooping (after ``excluded``)
    excluded : list of str, ids left out by the caller
    steps : list of SnoopStep, in order
    snooped : bool, whether snooping ran
    stopped : str, why snooping ended ("" when it did not run)
    """

    result: HelmertResult
    initial: HelmertResult
    excluded: list[str] = field(default_factory=list)
    steps: list[SnoopStep] = field(default_factory=list)
    snooped: bool = False
    stopped: str = ""

    def __repr__(self) -> str:
        gone = ", ".join(s.removed for s in self.steps) or "none"
        return (f"Snooping({len(self.result.ids)} points, excluded "
                f"{', '.join(self.excluded) or 'none'}, removed {gone})")

    @property
    def removed(self) -> list[str]:
        """The ids data snooping removed, in order."""
        return [s.removed for s in self.steps]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: excluded ids, the snooping steps and why it stopped."""
        return {"excluded": list(self.excluded),
                "snooping": {"method": "Baarda 1968 iterative data snooping",
                             "alpha0": 0.001,
                             "steps": [s.__dict__.copy() for s in self.steps],
                             "removed": self.removed, "stopped": self.stopped}
                if self.snooped else None,
                "initial_outliers": self.initial.outlier_tests}


def _rows(sig: ArrayLike | None, n: int, name: str) -> np.ndarray | None:
    """Sigmas as (n, 3) rows to select from (values are checked by ``fit_helmert``)."""
    if sig is None:
        return None
    v = np.asarray(sig, dtype=np.float64)
    if v.ndim == 0:
        return np.full((n, 3), float(v))
    if v.shape == (n,):
        return np.repeat(v[:, None], 3, axis=1)
    if v.shape == (n, 3):
        return v
    raise HelmertError(f"Expected `{name}` as one value, (n,) or (n, 3) for n = {n}, got "
                       f"shape {v.shape}.")


def _too_few(n: int, model: str) -> bool:
    """Whether n points leave no redundancy to test (3n - u < 2, or n < 3)."""
    return n < 3 or 3 * n - MODELS[model] < 2


def data_snooping(source: ArrayLike, target: ArrayLike, *, ids: Iterable[object],
                  model: HelmertModel = 7, sigma_source_m: ArrayLike | None = None,
                  sigma_target_m: ArrayLike | None = None, exclude: Iterable[str] = (),
                  snoop: bool = True, max_removed: int | None = None,
                  use_apriori: bool | None = None, max_iter: int = 50,
                  allow_reflection: bool = False, allow_scale: bool = False) -> Snooping:
    """Helmert adjustment with the points ``exclude`` left out and, with ``snoop``,
    Baarda's iterative data snooping (module doc).

    Parameters
    ----------
    source, target : (n, 3) array_like of float, the same points in both systems (m)
    ids : (n,) sequence, the point names (``exclude`` and the steps refer to them)
    model, use_apriori, max_iter, allow_reflection, allow_scale
        As in ``fit_helmert``.
    sigma_source_m, sigma_target_m : array_like of float or None
        As in ``fit_helmert``; None, one value, (n,) or (n, 3) (m).
    exclude : ids to leave out before the first adjustment
    snoop : bool, run data snooping (False: only ``exclude``)
    max_removed : int or None, remove at most this many points (None: until no test
        exceeds its critical value, or too few points are left to test)

    Returns
    -------
    Snooping

    Raises
    ------
    HelmertError
        An id of ``exclude`` that is not among ``ids``; anything ``fit_helmert`` raises
        for the first adjustment.
    """
    name = model_name(model)
    id_list = [str(i) for i in ids]
    src = np.asarray(source, dtype=np.float64)
    dst = np.asarray(target, dtype=np.float64)
    n = len(id_list)
    if src.shape != (n, 3) or dst.shape != (n, 3):
        raise HelmertError(f"Expected source and target of shape ({n}, 3), one row per id, "
                           f"got {src.shape} and {dst.shape}.")
    sig = {"s": _rows(sigma_source_m, n, "sigma_source_m"),
           "t": _rows(sigma_target_m, n, "sigma_target_m")}
    excluded = [str(k) for k in exclude]
    unknown = [k for k in excluded if k not in id_list]
    if unknown:
        shown = ", ".join(id_list[:8]) + (", ..." if n > 8 else "")
        raise HelmertError(f"Expected ids to exclude among the {n} matched points "
                           f"({shown}), got {', '.join(unknown)}.")
    keep = np.array([k not in excluded for k in id_list])

    def fit(mask: np.ndarray) -> HelmertResult:
        return fit_helmert(
            src[mask], dst[mask], model=model, ids=[k for k, m in zip(id_list, mask) if m],
            sigma_source_m=None if sig["s"] is None else sig["s"][mask],
            sigma_target_m=None if sig["t"] is None else sig["t"][mask],
            use_apriori=use_apriori, max_iter=max_iter,
            allow_reflection=allow_reflection, allow_scale=allow_scale)

    res = initial = fit(keep)
    out = Snooping(res, initial, excluded, snooped=snoop)
    if not snoop:
        return out
    steps: list[SnoopStep] = []
    while True:
        if not res.outliers:
            out.stopped = (f"no {res.test}-test above the critical value "
                           f"{res.critical:.2f}")
            break
        worst = res.outliers[0]
        if max_removed is not None and len(steps) >= max_removed:
            out.stopped = (f"stopped after {max_removed} removals (max_removed); "
                           f"{worst} still above the critical value")
            break
        if _too_few(int(keep.sum()) - 1, name):
            out.stopped = (f"stopped: removing {worst} would leave too few points to test "
                           f"({int(keep.sum()) - 1} for a {name}-parameter model)")
            break
        trial = keep.copy()
        trial[id_list.index(worst)] = False
        try:
            after = fit(trial)
        except HelmertError as exc:
            out.stopped = f"stopped: without {worst} the adjustment fails ({exc})"
            break
        at = res.ids.index(worst)
        steps.append(SnoopStep(worst, float(res.w_tests[at]), res.test, float(res.critical),
                               float(after.sigma0), len(after.ids), len(after.outliers)))
        keep, res = trial, after
    out.result, out.steps = res, steps
    return out
