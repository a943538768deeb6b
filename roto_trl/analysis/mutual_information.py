"""Mutual information between latents and physical state: PCA, then the KSG estimator.

The paper (Section 6, Q4) reduces the latent z to 13 principal components and estimates I(z; s)
with the Kraskov-Stögbauer-Grassberger estimator (its first algorithm, K = 4 neighbours), and
I(z; s_j) per state element. Both sides are multi-dimensional, which the maintained libraries
we checked do not cover: ``ennemi`` and scikit-learn's ``mutual_info_regression`` estimate MI
between one-dimensional variables (one column at a time). So the estimator is written here and
validated against the closed form for correlated Gaussians (``tests/test_analysis.py``). It
finds neighbours by brute force in blocks of rows with torch: in 13 + 14 dimensions a KD-tree
(SciPy's) took minutes for 5000 samples, the exact distances take about a second.
"""

from __future__ import annotations

import numpy as np
import torch

JITTER = 1e-8  # breaks ties of discrete-valued columns (counters, contacts), which bias KSG
BLOCK_ROWS = 1024  # distance rows per block: [BLOCK_ROWS, N] float64 matrices, ~40 MB at N = 5000


def pca(x: np.ndarray, components: int) -> tuple[np.ndarray, np.ndarray]:
    """Project ``x`` ``[N, D]`` on its first ``components`` principal axes.

    Returns:
        ``(scores [N, components], explained [components])``, the fraction of the variance
        each axis explains.
    """
    if x.ndim != 2 or not 1 <= components <= min(x.shape):
        raise ValueError(
            f"pca needs [N, D] data with 1 <= components <= min(N, D); got {x.shape}, {components}"
        )
    centred = x - x.mean(axis=0)
    _, sing, vt = np.linalg.svd(centred, full_matrices=False)
    variance = sing**2
    return centred @ vt[:components].T, variance[:components] / variance.sum()


def _standardise(x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    x = x.reshape(len(x), -1)
    std = x.std(axis=0)
    x = (x - x.mean(axis=0)) / np.where(std > 0, std, 1.0)
    return x + JITTER * rng.standard_normal(x.shape)


def _max_norm_distances(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``[len(a), len(b)]`` max-norm distances (one column at a time: ``torch.cdist`` with
    ``p=inf`` is several times slower on CPU)."""
    out = torch.zeros(len(a), len(b), dtype=a.dtype)
    for j in range(a.shape[1]):
        torch.maximum(out, (a[:, j, None] - b[None, :, j]).abs(), out=out)
    return out


def ksg_mutual_information(x: np.ndarray, y: np.ndarray, k: int = 4, seed: int = 0) -> float:
    """KSG estimate (algorithm 1, max-norm) of I(x; y) in nats.

    Args:
        x: ``[N]`` or ``[N, Dx]`` samples.
        y: ``[N]`` or ``[N, Dy]`` samples, paired with ``x`` row by row.
        k: neighbours in the joint space.
        seed: seed of the tie-breaking jitter.

    Each column is standardised first. I = ψ(k) + ψ(N) - <ψ(n_x + 1) + ψ(n_y + 1)>, where n_x,
    n_y count the other points strictly closer in x (in y) than the k-th joint neighbour.
    """
    if len(x) != len(y):
        raise ValueError(f"x and y need the same number of samples, got {len(x)} and {len(y)}")
    n = len(x)
    if isinstance(k, bool) or not isinstance(k, int) or k < 1:
        raise ValueError(f"KSG needs k >= 1 neighbours, got k={k!r}")
    if n <= k:
        raise ValueError(f"KSG with k={k} needs more than {k} samples, got {n}")
    rng = np.random.default_rng(seed)
    x = torch.from_numpy(_standardise(x, rng))
    y = torch.from_numpy(_standardise(y, rng))
    n_x = torch.empty(n, dtype=torch.float64)
    n_y = torch.empty(n, dtype=torch.float64)
    for start in range(0, n, BLOCK_ROWS):
        rows = slice(start, min(start + BLOCK_ROWS, n))
        dx, dy = _max_norm_distances(x[rows], x), _max_norm_distances(y[rows], y)
        joint = torch.maximum(dx, dy)
        # the k-th neighbour other than the point itself (its own distance 0 is the 1st smallest)
        radius = joint.kthvalue(k + 1, dim=1).values.unsqueeze(1)
        n_x[rows] = (dx < radius).sum(1) - 1.0
        n_y[rows] = (dy < radius).sum(1) - 1.0
    digamma = torch.special.digamma
    value = digamma(torch.tensor(float(k))) + digamma(torch.tensor(float(n)))
    return float(value - (digamma(n_x + 1) + digamma(n_y + 1)).mean())


def latent_state_information(
    z: np.ndarray, state: np.ndarray, components: int = 13, k: int = 4, seed: int = 0
) -> tuple[float, np.ndarray]:
    """I(PCA(z); s) and I(PCA(z); s_j) for each state element j.

    Args:
        z: ``[N, Z]`` latents.
        state: ``[N, S]`` physical states paired with them.

    Returns:
        ``(joint, marginals [S])`` in nats.
    """
    reduced, _ = pca(np.asarray(z, dtype=np.float64), components)
    joint = ksg_mutual_information(reduced, state, k, seed)
    marginals = np.array(
        [ksg_mutual_information(reduced, state[:, j], k, seed) for j in range(state.shape[1])]
    )
    return joint, marginals
