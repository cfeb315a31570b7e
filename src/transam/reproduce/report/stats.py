"""Percentile-bootstrap confidence intervals over seeds, as rliable computes them.

rliable is not installable next to this stack (its ``arch`` dependency fails under pandas 3),
so this is the same method in numpy: resample the *seeds* (runs) with replacement, recompute
the statistic, take the 2.5th and 97.5th percentiles. Where several tasks (strata) enter one
statistic, seeds are resampled within each stratum (rliable's stratified bootstrap), so every
resample keeps each stratum's size.

A resample is represented by its count weights (how often each seed was drawn, divided by the
stratum size), so a statistic over a long vector (a learning curve, a per-timestep curve) is
one matrix product instead of a (resamples x seeds x length) copy.

Every call starts from the same fixed RNG seed: the report is deterministic and does not
depend on the order in which the cells are computed.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

RESAMPLES = 10_000
CONFIDENCE = 0.95
RNG_SEED = 0


@dataclass(frozen=True)
class Interval:
    """A point estimate with its bootstrap interval (``lo == hi == mean`` when n = 1)."""

    mean: float
    lo: float
    hi: float
    n: int


def _check(values: np.ndarray, what: str) -> np.ndarray:
    if values.ndim == 0 or values.shape[0] == 0:
        raise ValueError(f"{what}: need at least one seed, got shape {values.shape}")
    if not np.all(np.isfinite(values)):
        raise ValueError(f"{what}: values must be finite, got {values.tolist()}")
    return values


def stratified_resample_indices(
    sizes: Sequence[int], resamples: int, rng: np.random.Generator
) -> list[np.ndarray]:
    """Indices into the concatenation of the strata, one (resamples, size_k) array per stratum:
    each resample of stratum k draws size_k seeds with replacement from stratum k only."""
    if any(s < 1 for s in sizes):
        raise ValueError(f"every stratum needs at least one seed, got sizes {list(sizes)}")
    offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    return [
        o + rng.integers(0, s, size=(resamples, s)) for o, s in zip(offsets, sizes, strict=True)
    ]


def _weights(idx: np.ndarray, start: int, size: int) -> np.ndarray:
    """(resamples, size) draw counts / size: the resampled mean is ``weights @ values``."""
    rows = idx.shape[0]
    flat = (np.arange(rows)[:, None] * size + (idx - start)).ravel()
    return np.bincount(flat, minlength=rows * size).reshape(rows, size) / size


def stratified_bootstrap(
    strata: Sequence[np.ndarray | Sequence[float]],
    coefficients: Sequence[float] | None = None,
    resamples: int = RESAMPLES,
    confidence: float = CONFIDENCE,
    seed: int = RNG_SEED,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CI of ``sum_k c_k * mean(stratum_k)`` (default c_k = 1/K: the mean of the per-stratum
    means), resampling seeds within each stratum. A stratum is (seeds,) or (seeds, length);
    returns (point, lo, hi), each scalar or (length,). Coefficients (1, -1) give the CI of a
    difference of two independent means."""
    arrays = [_check(np.asarray(s, dtype=float), f"stratum {k}") for k, s in enumerate(strata)]
    if not arrays:
        raise ValueError("no strata")
    if len({a.shape[1:] for a in arrays}) != 1:
        raise ValueError(f"strata disagree in shape: {[a.shape for a in arrays]}")
    coef = np.full(len(arrays), 1.0 / len(arrays)) if coefficients is None else coefficients
    if len(coef) != len(arrays):
        raise ValueError(f"{len(coef)} coefficients for {len(arrays)} strata")
    point = sum(c * a.mean(axis=0) for c, a in zip(coef, arrays, strict=True))
    point = np.asarray(point, dtype=float)
    if all(a.shape[0] == 1 for a in arrays):  # nothing to resample: the CI is the point
        return point, point.copy(), point.copy()
    rng = np.random.default_rng(seed)
    sizes = [a.shape[0] for a in arrays]
    indices = stratified_resample_indices(sizes, resamples, rng)
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    stats = np.zeros((resamples, *arrays[0].shape[1:]))
    for c, a, idx, start in zip(coef, arrays, indices, starts, strict=True):
        flat = a.reshape(a.shape[0], -1)
        stats += c * (_weights(idx, int(start), a.shape[0]) @ flat).reshape(stats.shape)
    tail = 100.0 * (1.0 - confidence) / 2.0
    lo, hi = np.percentile(stats, [tail, 100.0 - tail], axis=0)
    return point, np.asarray(lo), np.asarray(hi)


def bootstrap_ci(
    values: np.ndarray | Sequence[float],
    resamples: int = RESAMPLES,
    confidence: float = CONFIDENCE,
    seed: int = RNG_SEED,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mean, lo, hi) of the mean over seeds (axis 0), vectorised over any trailing axes."""
    return stratified_bootstrap([values], [1.0], resamples, confidence, seed)


def interval(values: Sequence[float]) -> Interval:
    """The mean over seeds and its 95% percentile-bootstrap CI."""
    mean, lo, hi = bootstrap_ci(values)
    return Interval(float(mean), float(lo), float(hi), len(values))


def difference(a: Sequence[float], b: Sequence[float]) -> Interval:
    """mean(a) - mean(b) for independent seed sets, each resampled within itself; ``n`` is the
    smaller of the two seed counts."""
    point, lo, hi = stratified_bootstrap([a, b], [1.0, -1.0])
    return Interval(float(point), float(lo), float(hi), min(len(a), len(b)))


def curve_ci(matrix: np.ndarray) -> dict[str, list[float | None] | list[int]]:
    """Mean and CI per column of a (seeds, points) matrix holding NaN where a seed has no value
    (an unfinished run): each column uses the seeds it has; columns with the same seeds share
    one vectorised bootstrap."""
    m = np.asarray(matrix, dtype=float)
    cols = m.shape[1]
    mean: list[float | None] = [None] * cols
    lo: list[float | None] = [None] * cols
    hi: list[float | None] = [None] * cols
    present = ~np.isnan(m)
    n = present.sum(axis=0)
    patterns: dict[bytes, list[int]] = {}
    for j in range(cols):
        if n[j]:
            patterns.setdefault(present[:, j].tobytes(), []).append(j)
    for key, js in patterns.items():
        rows = np.frombuffer(key, dtype=bool)
        p, a, b = bootstrap_ci(m[np.ix_(rows, np.asarray(js))])
        for k, j in enumerate(js):
            mean[j], lo[j], hi[j] = float(p[k]), float(a[k]), float(b[k])
    return {"mean": mean, "lo": lo, "hi": hi, "n": [int(x) for x in n]}
