"""Confidence intervals of the evaluation's statistics.

:func:`bootstrap_ci`: percentile bootstrap (:func:`scipy.stats.bootstrap`; Efron & Tibshirani, "An
Introduction to the Bootstrap", 1993, ch. 13), resampling whole scenes when groups are given, since
probes of one scene are not independent.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any, cast

import numpy as np
from scipy import stats

__all__ = ["bootstrap_ci", "summarise"]


def _cluster_bootstrap(
    v: np.ndarray,
    group_index: np.ndarray,
    n_groups: int,
    statistic: Callable[..., Any],
    n: int,
    rng: np.random.Generator,
) -> np.ndarray | None:
    """``statistic`` (``np.mean`` or ``np.median``) of ``n`` cluster resamples, vectorised: each
    resample draws ``n_groups`` groups with replacement and takes every value of each drawn group
    (as often as it was drawn). ``None`` for another statistic."""
    idx = rng.integers(0, n_groups, size=(n, n_groups))
    counts = np.zeros((n, n_groups))
    np.add.at(counts, (np.arange(n)[:, None], idx), 1.0)
    w = counts[:, group_index]  # (n, N): how often each value is in each resample
    if statistic is np.mean:
        return cast(np.ndarray, (w @ v) / w.sum(axis=1))
    if statistic is np.median:
        order = np.argsort(v, kind="stable")
        vs, cum = v[order], np.cumsum(w[:, order], axis=1)
        total = cum[:, -1].astype(np.int64)
        lo = (cum <= ((total - 1) // 2)[:, None]).sum(axis=1)  # first sorted value past position (T-1)//2
        hi = (cum <= (total // 2)[:, None]).sum(axis=1)
        return cast(np.ndarray, 0.5 * (vs[lo] + vs[hi]))
    return None


def bootstrap_ci(
    values: Sequence[float] | np.ndarray,
    statistic: Callable[[np.ndarray], float] = np.median,
    groups: Sequence[Any] | None = None,
    *,
    n_resamples: int = 2000,
    level: float = 0.95,
    seed: int = 0,
) -> tuple[float, float]:
    """Percentile bootstrap confidence interval of ``statistic(values)`` (NaNs dropped).

    With ``groups`` (e.g. scene ids, one per value) whole groups are resampled (cluster bootstrap),
    since values of one scene are correlated; SciPy has no cluster bootstrap, so for the mean and
    the median it is done here, vectorised (other statistics go through SciPy with the scenes as
    the resampled data). Without groups: :func:`scipy.stats.bootstrap` (``method="percentile"``).
    Returns ``(low, high)``; ``(nan, nan)`` without values; the statistic itself for a constant
    sample or a single group.
    """
    v = np.asarray(values, dtype=np.float64)
    keep = np.isfinite(v)
    v = v[keep]
    rng = np.random.default_rng(seed)
    if v.size == 0:
        return math.nan, math.nan
    if np.all(v == v[0]):
        return float(statistic(v)), float(statistic(v))
    alpha = 100 * (1 - level) / 2
    if groups is None:
        if v.size < 2:
            return float(statistic(v)), float(statistic(v))
        vec = statistic in (np.mean, np.median)
        res = stats.bootstrap(
            (v,),
            statistic,
            n_resamples=n_resamples,
            confidence_level=level,
            method="percentile",
            random_state=rng,
            vectorized=vec,
            **({"axis": -1} if vec else {}),
        )
        return float(res.confidence_interval.low), float(res.confidence_interval.high)
    g = np.asarray(list(groups), dtype=object)[keep]
    names = list(dict.fromkeys(g.tolist()))
    if len(names) < 2:
        return float(statistic(v)), float(statistic(v))
    gi = np.array([names.index(x) for x in g.tolist()])
    boot = _cluster_bootstrap(v, gi, len(names), statistic, n_resamples, rng)
    if boot is None:
        members = [v[gi == k] for k in range(len(names))]
        res = stats.bootstrap(
            (np.arange(len(names)),),
            lambda idx: statistic(np.concatenate([members[int(i)] for i in idx])),
            n_resamples=n_resamples,
            confidence_level=level,
            method="percentile",
            random_state=rng,
            vectorized=False,
        )
        return float(res.confidence_interval.low), float(res.confidence_interval.high)
    lo, hi = np.percentile(boot, [alpha, 100 - alpha])
    return float(lo), float(hi)


def summarise(
    values: Sequence[float] | np.ndarray, groups: Sequence[Any] | None = None, seed: int = 0
) -> dict[str, Any]:
    """``n``, median and mean of ``values`` (NaNs dropped), each with its 95 % bootstrap interval."""
    v = np.asarray(values, dtype=np.float64)
    finite = np.isfinite(v)
    out: dict[str, Any] = {"n": int(finite.sum())}
    for name, fn in (("median", np.median), ("mean", np.mean)):
        out[name] = float(fn(v[finite])) if finite.any() else None
        out[f"{name}_ci"] = list(bootstrap_ci(v, fn, groups, seed=seed)) if finite.any() else [None, None]
    return out
