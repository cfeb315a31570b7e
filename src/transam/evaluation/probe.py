"""What an agent model's embeddings encode about the partner: a linear probe of the partner
index at each in-episode step, and a 2-D projection (PCA).

The probe predicts the partner index from the embedding z_t the policy acted on at step t,
separately for every t: episodes are split half/half, stratified by partner, with a fixed seed;
features are standardised with the training half's statistics; the probe is ridge regression
on one-hot partner targets (closed form, :data:`PROBE_RIDGE`), predicting the argmax. It is
deterministic and needs no iterative fitting.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

PROBE_RIDGE = 1.0
"""Ridge penalty of the probe, on standardised features (unit variance each): small next to
the ~N/2 training episodes, so it only regularises directions the data barely constrain (with
embed_dim > N/2 the unpenalised least squares would interpolate the training half)."""


def stratified_split(labels: np.ndarray, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(train, test) episode indices: each class shuffled, the classes laid end to end and the
    positions dealt alternately to train and test, so each class (and the whole) splits in
    half to within one episode."""
    rng = np.random.default_rng(seed)
    classes = np.unique(labels)
    order = np.concatenate([rng.permutation(np.flatnonzero(labels == c)) for c in classes])
    return np.sort(order[0::2]), np.sort(order[1::2])


def probe_accuracy(
    x_train: np.ndarray,
    y_train: np.ndarray,
    x_test: np.ndarray,
    y_test: np.ndarray,
    ridge: float = PROBE_RIDGE,
) -> float:
    """Test accuracy of a ridge-regression probe on one-hot labels (features standardised with
    the training statistics; the intercept is the class frequencies, unpenalised)."""
    x_train, x_test = np.asarray(x_train, np.float64), np.asarray(x_test, np.float64)
    mean, std = x_train.mean(0), x_train.std(0)
    std = np.where(std > 1e-8, std, 1.0)
    a, b = (x_train - mean) / std, (x_test - mean) / std
    classes = np.unique(y_train)
    onehot = (y_train[:, None] == classes[None]).astype(np.float64)
    prior = onehot.mean(0)
    target = onehot - prior
    n, d = a.shape
    if d <= n:
        w = np.linalg.solve(a.T @ a + ridge * np.eye(d), a.T @ target)
    else:  # the dual form: an n x n system
        w = a.T @ np.linalg.solve(a @ a.T + ridge * np.eye(n), target)
    pred = classes[np.argmax(b @ w + prior, -1)]
    return float((pred == y_test).mean())


def linear_probe(z: np.ndarray, live: np.ndarray, labels: np.ndarray, seed: int) -> dict[str, Any]:
    """Probe the partner index from ``z`` [T, N, D] at each step t, over the episodes running
    at t (``live`` [T, N]); ``labels`` [N]."""
    train, test = stratified_split(labels, seed)
    per_step: list[float | None] = []
    for t in range(z.shape[0]):
        tr, te = train[live[t, train] > 0], test[live[t, test] > 0]
        if len(tr) == 0 or len(te) == 0:
            per_step.append(None)
            continue
        per_step.append(probe_accuracy(z[t, tr], labels[tr], z[t, te], labels[te]))
    scored = [a for a in per_step if a is not None]
    chance = np.bincount(labels[test]).max() / len(test) if len(test) else math.nan
    return {
        "accuracy": float(np.mean(scored)) if scored else None,
        "per_step": per_step,
        "chance": float(chance),
        "train_episodes": len(train),
        "test_episodes": len(test),
        "features": f"embedding z_t (dim {z.shape[-1]})",
        "ridge": PROBE_RIDGE,
    }


def pca_2d(x: np.ndarray) -> tuple[np.ndarray, list[float]]:
    """(coordinates [N, 2], fraction of the total variance each axis explains)."""
    x = np.asarray(x, np.float64)
    centered = x - x.mean(0)
    _, s, vt = np.linalg.svd(centered, full_matrices=False)
    coords = np.zeros((len(x), 2))
    k = min(2, vt.shape[0])
    coords[:, :k] = centered @ vt[:k].T
    var = s**2
    total = var.sum()
    ratio = [float(var[i] / total) if i < k and total > 0 else 0.0 for i in range(2)]
    return coords, ratio
