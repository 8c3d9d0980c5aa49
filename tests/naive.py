"""Naive NumPy loop-over-points references of every score and of FPS (REFERENCE.md, literally).

Deliberately slow and simple: brute-force neighbours, one ``np.linalg.eigh`` per point.
"""

from __future__ import annotations

import itertools
import math

import numpy as np


def resolution(points):
    p = np.asarray(points, dtype=np.float64)
    d = np.linalg.norm(p[:, None] - p[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    return float(d.min(axis=1).mean())


def _kernel_spectrum(d, k=3):
    h = (k - 1) // 2
    c = np.array(list(itertools.product(range(-h, h + 1), repeat=3)), dtype=np.float64) * d
    cn = c - c.mean(axis=1, keepdims=True)
    lam, v = np.linalg.eigh(cn @ cn.T)
    return c, lam / lam.max(), v


def voxel_signal(points, i, c, d):
    s = np.zeros(len(c))
    for j, cj in enumerate(c):
        for q in points:
            if np.all(np.abs(q - points[i] - cj) < d / 2):
                s[j] += 1
    return s


def hkc_point(p, i, c, lam, v, d):
    """Reference beta (Eq. 11) of point i, straight from REFERENCE.md."""
    s = voxel_signal(p, i, c, d)
    high = v @ np.diag(1 - lam) @ v.T @ s
    low = s - high
    nl = np.linalg.norm(low)
    return np.linalg.norm(high) / nl if nl > 1e-9 * np.linalg.norm(s) else np.inf


def hkc(points, d_factor=1.3, k=3):
    p = np.asarray(points, dtype=np.float64)
    d = d_factor * resolution(p)
    c, lam, v = _kernel_spectrum(d, k)
    return np.array([hkc_point(p, i, c, lam, v, d) for i in range(len(p))])


def hkf(points, d_factor=1.3, k=3):
    p = np.asarray(points, dtype=np.float64)
    d = d_factor * resolution(p)
    c, lam, _ = _kernel_spectrum(d, k)
    _, _, v = _kernel_spectrum(1.0, k)  # the basis hgjax fixes: eigh of R at unit spacing
    t = int(np.argmax(np.diff(lam)) + 1)
    out = np.empty(len(p))
    for i in range(len(p)):
        s_hat = np.abs(v.T @ voxel_signal(p, i, c, d))
        out[i] = s_hat[:t].sum() / s_hat.sum()
    return out


def hkc_invariant_point(p, i, d, k=3):
    """hgjax's default beta of point i: the kernel turned into the local frame, energies
    averaged over the frame's 8 axis-sign choices (each with the paper's projector)."""
    o = p - p[i]
    ball = o[np.linalg.norm(o, axis=1) < np.sqrt(3) * k * d / 2]
    y = ball / d - (ball / d).mean(axis=0)
    _, frame = np.linalg.eigh(y.T @ y)
    c, lam, v = _kernel_spectrum(d, k)
    high2 = low2 = 0.0
    for signs in itertools.product((1.0, -1.0), repeat=3):
        q = (ball @ frame) * np.array(signs)
        s = np.array([np.all(np.abs(q - cj) < d / 2, axis=1).sum() for cj in c], dtype=np.float64)
        high = v @ np.diag(1 - lam) @ v.T @ s
        high2, low2 = high2 + high @ high / 8, low2 + (s - high) @ (s - high) / 8
    return np.sqrt(high2) / np.sqrt(low2) if low2 > 1e-18 * (high2 + low2) else np.inf


def hkc_invariant(points, d_factor=1.3, k=3):
    p = np.asarray(points, dtype=np.float64)
    d = d_factor * resolution(p)
    return np.array([hkc_invariant_point(p, i, d, k) for i in range(len(p))])


def knn_rows(points, n):
    p = np.asarray(points, dtype=np.float64)
    d = np.linalg.norm(p[:, None] - p[None], axis=-1)
    return np.argsort(d, axis=1, kind="stable")[:, :n]


def lhf_point(p, i, n):
    """Reference gamma (Eq. 14) of point i: brute-force neighbours, one n x n eigh."""
    rows = np.argsort(np.linalg.norm(p - p[i], axis=1), kind="stable")[:n]
    s = p[rows] - p[i]
    sn = s - s.mean(axis=1, keepdims=True)
    lam, v = np.linalg.eigh(sn @ sn.T)
    lam = np.abs(lam) / np.abs(lam).max()
    t = int(np.argmax(np.diff(lam)) + 1)
    tt = np.abs(v.T @ s)
    return tt[:t].sum() / tt.sum()


def lhf_single(points, n):
    p = np.asarray(points, dtype=np.float64)
    return np.array([lhf_point(p, i, n) for i in range(len(p))])


def lhf(points, ratio, lengths):
    ga, gb = lhf_single(points, lengths[0]), lhf_single(points, lengths[1])
    m = int(np.ceil(ratio * len(ga)))
    big_a, big_b = np.sort(ga)[::-1][m - 1], np.sort(gb)[::-1][m - 1]
    eps = big_b / (big_a + big_b)
    return eps * ga + (1 - eps) * gb


def haar_l1_factor(d):
    """d c_d = E ||Q^T x||_1 / ||x||_2 for Q a Haar-random orthonormal basis of R^d."""
    return d * math.gamma(d / 2) / (math.sqrt(math.pi) * math.gamma((d + 1) / 2))


def eigenspaces(lam, tol):
    """Groups of consecutive column indices whose ascending eigenvalues agree within tol."""
    groups, start = [], 0
    for j in range(1, len(lam) + 1):
        if j == len(lam) or lam[j] - lam[start] > tol:
            groups.append(list(range(start, j)))
            start = j
    return groups


def lhf_invariant_signal(s, lam, v):
    """Rotation-invariant gamma of one signal s (n, 3) from ANY eigenbasis (lam, v) of R = s_c s_c^T.

    s_c = s minus its column means (the neighbourhood centroid). Eq. (14) with the L2 norm of
    each coefficient row ||(V^T s)[j]||_2 in place of its L1 norm (the L1 averaged over random
    rotations of the cloud, up to the common factor 3/2), and the null eigenspace (the first
    d = max(n - 3, 1) columns) averaged over its bases: d c_d ||V_null^T s||_F.
    """
    n = len(s)
    if np.abs(lam).max() == 0:
        return 0.0
    lam = np.abs(lam) / np.abs(lam).max()
    t = int(np.argmax(np.diff(lam)) + 1)
    rows = np.linalg.norm(v.T @ s, axis=1)
    d = max(n - 3, 1)
    null = haar_l1_factor(d) * np.linalg.norm(rows[:d])
    high, total = null + rows[d:t].sum(), null + rows[d:].sum()
    return high / total if total > 0 else 0.0


def lhf_invariant_spectrum(s):
    """(lam, V) of R = s_c s_c^T for one signal, s_c column-centred (NumPy eigh)."""
    sc = s - s.mean(axis=0)
    return np.linalg.eigh(sc @ sc.T)


def lhf_single_invariant(points, n):
    """Rotation-invariant LHF gamma (hgjax's default) through one n x n eigh per point."""
    p = np.asarray(points, dtype=np.float64)
    rows = knn_rows(p, n)
    out = np.empty(len(p))
    for i in range(len(p)):
        s = p[rows[i]] - p[i]
        out[i] = lhf_invariant_signal(s, *lhf_invariant_spectrum(s))
    return out


def ea(points, k=16):
    """EA surface variation l0 / (l0 + l1 + l2) of the k nearest points (the point itself
    first), one ``np.linalg.eigvalsh`` per point; 0 where the neighbours coincide."""
    p = np.asarray(points, dtype=np.float64)
    out = np.empty(len(p))
    for i, rows in enumerate(knn_rows(p, k)):
        y = p[rows] - p[rows].mean(axis=0)
        lam = np.linalg.eigvalsh(y.T @ y)
        out[i] = max(lam[0], 0) / lam.sum() if lam.sum() > 0 else 0.0
    return out


def fps(points, m, start=0):
    """Farthest point sampling: m indices from ``start``, each the farthest from those before it
    (ties by index)."""
    p = np.asarray(points, dtype=np.float64)
    chosen, min_d = [start], np.full(len(p), np.inf)
    for _ in range(m - 1):
        min_d = np.minimum(min_d, ((p - p[chosen[-1]]) ** 2).sum(1))
        min_d[chosen] = -1
        chosen.append(int(np.argmax(min_d)))
    return np.array(chosen)


def gfr_pairs(points, max_nn=100, radius_factor=None):
    """Stored GFR pairs (t, j), t < j, by brute force over all pairs; REFERENCE.md "GFR baseline".

    radius_factor None: the reference rules 1-3 on float32 squared distances. Otherwise the
    invariant graph: Euclidean radius radius_factor x (median distance to the nearest distinct
    point), each point keeps the points at its max_nn nearest distinct locations, a pair is
    stored when either end keeps it.
    Returns the sorted list of pairs and the (N, N) squared distances they were judged on.
    """
    p = np.asarray(points, dtype=np.float32 if radius_factor is None else np.float64)
    n = len(p)
    q = np.empty((n, n), dtype=p.dtype)
    for i in range(n):
        d = p[i] - p
        q[i] = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2]
    if radius_factor is None:
        nearest = []
        for i in range(n):
            hits = np.argsort(q[i], kind="stable")[:3]  # 3-nearest query, equal q by index
            if len(hits) > 1 and hits[0] == i and q[i, hits[1]] > 1e-10:
                nearest.append(math.sqrt(float(q[i, hits[1]])))
        if not nearest:
            return [], q
        min_nn, max_nn_dist = min(nearest), max(nearest)
        if min_nn == max_nn_dist:
            max_nn_dist = 5 * min_nn
        r = min(10 * min_nn, 2 * max_nn_dist)
        pairs = []
        for t in range(n):
            partners = sorted((q[t, j], j) for j in range(t + 1, n) if 0 < q[t, j] < r)
            pairs += [(t, j) for _, j in partners[:max_nn]]
        return sorted(pairs), q
    dist = np.sqrt(q)
    distinct = [dist[i][dist[i] > 0].min() for i in range(n) if (dist[i] > 0).any()]
    big_r = radius_factor * float(np.median(distinct)) if distinct else 0.0
    pairs = set()
    for i in range(n):
        partners = sorted((q[i, j], j) for j in range(n) if j != i and 0 < q[i, j] < big_r**2)
        locations = []  # the first max_nn distinct partner coordinates, in (q, index) order
        for _, j in partners:
            if tuple(p[j]) not in locations and len(locations) < max_nn:
                locations.append(tuple(p[j]))
        pairs |= {(min(i, j), max(i, j)) for _, j in partners if tuple(p[j]) in locations}
    return sorted(pairs), q


def gfr_naive(points, max_nn=100, radius_factor=None):
    """GFR scores ||(L P)_i||_2 with a dense N x N Laplacian on :func:`gfr_pairs`' graph.

    w = exp(-q^2 / (2 v)), v the population variance of q over the stored pairs (v in float64,
    q and w in float32 for the reference); W = W0 + W0^T, L = D - W; P in float64.
    """
    pairs, q = gfr_pairs(points, max_nn, radius_factor)
    p = np.asarray(points, dtype=np.float64)
    n = len(p)
    w = np.zeros((n, n))
    if pairs:
        qs = np.array([q[t, j] for t, j in pairs])
        two_v = qs.dtype.type(2 * qs.astype(np.float64).var())
        for (t, j), qq in zip(pairs, qs):
            w[t, j] = w[j, t] = np.exp(-(qq * qq) / two_v) if two_v > 0 else 0.0
    lap = np.diag(w.sum(axis=1)) - w
    return np.linalg.norm(lap @ p, axis=1)


def mss_noise(points, rows, noise_k=8, samples=1000):
    """MSS's cloud noise level: sqrt of the median surface variation of the ``noise_k`` nearest
    points over the seeded sample of ids (all ids up to ``samples``)."""
    n = len(points)
    sample = np.arange(n) if n <= samples else np.sort(np.random.default_rng(0).choice(n, samples, replace=False))
    return math.sqrt(np.median([_variation(points[rows[i, :noise_k]] - points[i]) for i in sample]))


def _variation(x):
    """Surface variation l0 / (l0 + l1 + l2) of the covariance of the points x (k, 3), eigenvalues
    clipped at 0; 0 where the points coincide."""
    lam = np.maximum(np.linalg.eigvalsh(np.cov(x.T, bias=True)), 0)
    return lam[0] / lam.sum() if lam.sum() > 0 else 0.0


def mss(points, weights, scales=(8, 16, 32), low=4, fine=(6, 12)):
    """MSS edge score (hgjax.scores.mss): softplus of the perceptron ``weights`` over the
    multi-scale features and the cloud's noise level, from brute-force k-nearest rows and one
    ``np.linalg.eigh`` per scale."""
    p = np.asarray(points, dtype=np.float64)
    rows = knn_rows(p, max(scales))
    noise = mss_noise(p, rows)
    w1, b1, w2, b2, w3, b3 = (np.asarray(w, np.float64) for w in weights)
    out = np.empty(len(p))
    for i in range(len(p)):
        x = p[rows[i]] - p[i]
        low_mean = x[:low].mean(axis=0)
        f, normals, radii = [], [], []
        for k in scales:
            cov = np.cov(x[:k].T, bias=True)
            lam, v = np.linalg.eigh(cov)
            lam, trace = np.maximum(lam, 0), np.trace(cov)
            shift = x[:k].mean(axis=0) - low_mean
            along = v[:, 0] @ shift
            r = np.sqrt(trace)
            f += [lam[0] / trace, lam[1] / trace, abs(along) / r, np.linalg.norm(shift - along * v[:, 0]) / r] \
                if trace > 0 else [0.0] * 4
            normals.append(v[:, 0])
            radii.append(r)
        f += [abs(normals[0] @ normals[2]), abs(normals[1] @ normals[2])]
        f += [radii[0] / radii[2], radii[1] / radii[2]] if radii[2] > 0 else [0.0, 0.0]
        f += [_variation(x[:k]) for k in fine]
        f.append(noise)
        h = np.tanh(np.tanh(np.asarray(f) @ w1 + b1) @ w2 + b2)
        out[i] = np.logaddexp(0.0, (h @ w3 + b3)[0])
    return out

