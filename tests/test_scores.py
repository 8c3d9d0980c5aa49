"""HGSP scores: fast kernels against the naive NumPy references, and the kernel test matrix.

The library path is ``hgjax.score(hgjax.neighbourhoods(p, method, **params), method, **params)``;
per-neighbourhood kernels take ``offsets`` (K, 3) = neighbours minus the point and ``valid`` (K,).
"""

import functools
import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import spearmanr

import hgjax
from hgjax import spectrum
from hgjax.scores import _common, ea, hkc, hkf, lhf, cubic_kernel


import naive
from conftest import TOL
from fixtures import lattice_shell, uniform_cloud

ONE_BLOCK = 1024  # eager chunk for the eigh-based kernels (see tests/test_api.py)
D_FACTOR = 2.5  # an explicit voxel-spacing factor, passed to both the library and the naive loop


def grid_cloud(jitter=0.0):
    """Points of an integer grid on the surface of a 5 x 5 x 5 box (sharp edges, symmetric).

    kNN neighbourhoods on an exact grid are ambiguous (equidistant neighbours); the LHF and EA
    cases use a 1e-4 jitter so both implementations see the same neighbour sets.
    """
    g = lattice_shell(5)
    return g + jitter * np.random.default_rng(0).normal(size=g.shape)


CLOUDS = {"random": uniform_cloud(120), "grid": grid_cloud(), "jittered_grid": grid_cloud(1e-4)}
RESOLUTION = {name: naive.resolution(p) for name, p in CLOUDS.items()}


def _close(got, want, dtype):
    got = np.asarray(got, dtype=np.float64)
    assert np.array_equal(np.isinf(got), np.isinf(want))
    f = np.isfinite(want)
    np.testing.assert_allclose(got[f], want[f], rtol=TOL[dtype], atol=TOL[dtype])


@functools.lru_cache(maxsize=None)
def _naive(name, cloud):
    p = CLOUDS[cloud]
    if name == "hkc":
        return naive.hkc_invariant(p, d_factor=D_FACTOR)
    if name == "hkc_reference":
        return naive.hkc(p, d_factor=D_FACTOR)
    if name == "hkf_reference":
        return naive.hkf(p)  # same d as the library call below: same R, same LAPACK basis
    if name == "hkf_invariant":
        b = naive.hkc_invariant(p, d_factor=D_FACTOR)
        with np.errstate(invalid="ignore"):
            return np.where(np.isinf(b), 1.0, b / (1 + b))
    if name == "lhf3_reference":
        return naive.lhf_single(p, 3)
    if name == "lhf8_invariant":
        return naive.lhf_single_invariant(p, 8)
    if name == "lhf_combined_invariant":
        ga, gb = naive.lhf_single_invariant(p, 5), naive.lhf_single_invariant(p, 9)
        m = int(np.ceil(0.2 * len(p)))
        big_a, big_b = np.sort(ga)[::-1][m - 1], np.sort(gb)[::-1][m - 1]
        eps = big_b / (big_a + big_b)
        return eps * ga + (1 - eps) * gb
    if name == "ea":
        return naive.ea(p, ea.DEFAULT_K)
    raise KeyError(name)


def host_score(p, method, **params):
    """The public host path: neighbourhoods, then score, as a NumPy array."""
    return np.asarray(hgjax.score(hgjax.neighbourhoods(p, method, **params), method, **params))


def lhf_single(p, n, **params):
    """Single-length LHF gamma on the n nearest points (the point itself first)."""
    eigh = params.get("variant") == "reference" or params.get("solver") == "eigh"
    nb = hgjax.knn(p, n)
    return np.asarray(lhf.single(nb, lengths=(n,), chunk_size=ONE_BLOCK if eigh else None, **params))[:, 0]


FAST = {
    "hkc": lambda p, **kw: host_score(p, "hkc", d_factor=D_FACTOR, **kw),
    "hkc_reference": lambda p, **kw: host_score(p, "hkc", variant="reference", d_factor=D_FACTOR, **kw),
    "hkf_reference": lambda p, **kw: host_score(p, "hkf", variant="reference", **kw),
    "hkf_invariant": lambda p, **kw: host_score(p, "hkf", d_factor=D_FACTOR, **kw),
    "lhf3_reference": lambda p, **kw: lhf_single(p, 3, variant="reference"),
    "lhf8_invariant": lambda p, **kw: lhf_single(p, 8),
    "lhf_combined_invariant": lambda p, **kw: lhf.combine(host_score(p, "lhf", lengths=(5, 9)),
                                                          hgjax._validate.n_keep(len(p), 0.2)),
    "ea": lambda p, **kw: host_score(p, "ea"),
}
KNN = ("lhf", "ea")  # exact-grid kNN rows are ambiguous: these run on the jittered grid

# The invariant HKC/HKF turn the kernel into the local frame, which the flat faces of the grid
# leave undetermined inside their plane (equal in-plane eigenvalues): random cloud only.
FRAME = ("hkc", "hkf_invariant")
CASES = [(name, cloud) for name in sorted(FAST) for cloud in ("random", "grid")
         if not ((name.startswith(KNN) or name in FRAME) and cloud == "grid")]
CASES += [(name, "jittered_grid") for name in sorted(FAST) if name.startswith(KNN)]


@pytest.mark.full
@pytest.mark.parametrize("name,cloud", CASES)
def test_fast_matches_naive(name, cloud, dtype):
    p = CLOUDS[cloud].astype(dtype)
    kw = {} if name.startswith(KNN) else {"resolution": RESOLUTION[cloud]}
    got = FAST[name](p, **kw)
    assert got.dtype == dtype and got.shape == (len(p),)
    _close(got, _naive(name, cloud), dtype)


@pytest.mark.parametrize("name", sorted(FAST))
def test_permuting_points_permutes_scores_and_repeats_bitwise(name):
    p = uniform_cloud(150, seed=5)
    perm = np.random.default_rng(0).permutation(150)
    base = FAST[name](p)
    np.testing.assert_array_equal(FAST[name](p[perm]), base[perm])
    np.testing.assert_array_equal(FAST[name](p), base)


def test_lhf_gram_solver_equals_eigh_solver():
    """The 3 x 3 covariance path equals the n x n eigh wherever rank(s_c) = 3 (otherwise eigh's
    basis mixes the null space with C's vanishing directions)."""
    rng = np.random.default_rng(6)
    slab = np.c_[rng.random((150, 2)), 0.05 * rng.random(150)]  # nearly planar: small mu0
    for p in (uniform_cloud(200, seed=6), slab):
        for n in (3, 6, 16):
            np.testing.assert_allclose(lhf_single(p, n, solver="gram"),
                                       lhf_single(p, n, solver="eigh"), rtol=1e-10, atol=1e-12)


def test_lhf_default_is_rotation_translation_and_scale_invariant(dtype):
    """Default LHF scores of a box union (well separated eigenvalues off the faces) under a random
    similarity: equal to rounding, and the kept set unchanged."""
    cloud = hgjax.eval.box_union_cloud(seed=3, n_points=4000, noise=0.1)
    p = cloud.points.astype(dtype)
    rot = Rotation.random(random_state=np.random.default_rng(21)).as_matrix()
    q = (3.7 * p.astype(np.float64) @ rot.T + [5.0, -2.0, 1.0]).astype(dtype)
    a, b = host_score(p, "lhf"), host_score(q, "lhf")
    np.testing.assert_allclose(b, a, rtol=0, atol=2e-4 if dtype == np.float32 else 1e-9)
    kept_a, kept_b = hgjax.resample(p, 0.2, method="lhf"), hgjax.resample(q, 0.2, method="lhf")
    assert len(np.intersect1d(kept_a, kept_b)) / len(kept_a) >= (0.99 if dtype == np.float32 else 1.0)
    # The reference variant row-centres along (1, 1, 1): it does depend on the orientation.
    ref_a, ref_b = (host_score(x, "lhf", variant="reference") for x in (p, q))
    assert np.abs(ref_a - ref_b).max() > 0.05


def _isotropic_signal(rng, n=7, scale=(1.0, 1.0, 1.0)):
    """(n, 3) signal (first row 0) whose centred rows have covariance eigenvalues ``scale`` and a
    non-zero centroid offset: scale (1, 1, 1) gives one 3-D eigenspace of R."""
    y = rng.normal(size=(n, 3))
    q, _ = np.linalg.qr(y - y.mean(axis=0))  # orthonormal columns, orthogonal to 1
    y = q * np.sqrt(np.asarray(scale))
    return y - y[0]


def _lhf_kernel(sig, solver="gram"):
    """Invariant gamma of one signal (its first row, the point itself, is 0) through lhf.gamma."""
    n = len(sig)
    return float(lhf.gamma(jnp.asarray(sig), jnp.ones(n, bool), lengths=(n,), solver=solver)[0])


def _spectrum(sig):
    lam, v = naive.lhf_invariant_spectrum(sig)
    lam = np.abs(lam) / np.abs(lam).max()
    return lam, v, int(np.argmax(np.diff(lam)) + 1)


def _l1_ratio(v, t, sig):
    a = np.abs(v.T @ sig)
    return a[:t].sum() / a.sum()


def test_lhf_reference_is_basis_dependent_but_close_for_longer_signals():
    """For n > 3 the null space is degenerate: the paper's L1 depends on the eigensolver basis.

    JAX and NumPy build R with different rounding, so their LAPACK calls pick different bases
    inside the null space. The reference variant then agrees with the naive loop only in rank
    (REFERENCE.md measured Spearman 0.90-0.98 between two LAPACK builds).
    """
    p = uniform_cloud(150, seed=7)
    got, want = lhf_single(p, 8, variant="reference"), naive.lhf_single(p, 8)
    assert spearmanr(got, want).statistic > 0.85


def _rotate_in_eigenspaces(v, lam, rng, tol=1e-9):
    """Apply a random orthogonal rotation inside every degenerate eigenspace of (lam, V)."""
    v = v.copy()
    start = 0
    for end in range(1, len(lam) + 1):
        if end == len(lam) or lam[end] - lam[start] > tol:
            if end - start > 1:
                q, _ = np.linalg.qr(rng.normal(size=(end - start, end - start)))
                v[:, start:end] = v[:, start:end] @ q
            start = end
    return v


def test_invariant_scores_do_not_depend_on_the_basis_inside_degenerate_eigenspaces():
    rng = np.random.default_rng(8)
    # HKF: the kernel's 25-dimensional high band.
    lam, v, t = cubic_kernel.reference_spectrum(3)
    s = rng.integers(0, 3, size=27).astype(np.float64)
    s[13] += 1
    base = spectrum.band_energies(jnp.asarray(v), t, jnp.asarray(s))
    l1_changed = False
    for _ in range(5):
        vr = _rotate_in_eigenspaces(v, lam, rng)
        rot = spectrum.band_energies(jnp.asarray(vr), t, jnp.asarray(s))
        np.testing.assert_allclose(rot[2:], base[2:], rtol=1e-12)  # L2 band energies: invariant
        l1_changed |= abs(float(rot[0] / rot[1] - base[0] / base[1])) > 1e-6
        sigma = hkf.sigma(jnp.asarray(cubic_kernel.integer_offsets(3)), jnp.asarray(s > 0), 1.0)
        h, l = float(rot[2]), float(rot[3])
        if (s > 1).any():
            continue  # the neighbourhood above encodes occupancy only
        assert float(sigma) == pytest.approx(h / (h + l), rel=1e-12)
    assert l1_changed  # the reference L1 ratio does change: that is the defect being avoided
    # LHF: rotations inside the (n - 3)-dimensional null space of R, and inside the 3-D
    # eigenspace of mu0 = mu1 = mu2 for the isotropic signal.
    for sig in (np.r_[np.zeros((1, 3)), rng.normal(size=(9, 3))], _isotropic_signal(rng)):
        lam, v, t = _spectrum(sig)
        want = _lhf_kernel(sig)
        assert _lhf_kernel(sig, solver="eigh") == pytest.approx(want, rel=1e-10)
        l1_changed = False
        for _ in range(5):
            vr = _rotate_in_eigenspaces(v, lam, rng)
            assert naive.lhf_invariant_signal(sig, lam, vr) == pytest.approx(want, rel=1e-10)
            l1_changed |= abs(_l1_ratio(vr, t, sig) - _l1_ratio(v, t, sig)) > 1e-6
        assert l1_changed


def _result_dtypes(jaxpr):
    """dtypes of every (non-weak) equation result in a jaxpr and its sub-jaxprs."""
    for eqn in jaxpr.eqns:
        yield from (v.aval.dtype for v in eqn.outvars if not v.aval.weak_type)
        for param in eqn.params.values():
            for sub in param if isinstance(param, (tuple, list)) else (param,):
                sub = getattr(sub, "jaxpr", sub)
                if hasattr(sub, "eqns"):
                    yield from _result_dtypes(sub)


def test_lhf_gram_kernel_computes_in_the_callers_float32():
    """No silent float64 promotion under x64 (NumPy float64 constants would cause one)."""
    f = functools.partial(lhf.gamma, lengths=(4, 8))
    jaxpr = jax.make_jaxpr(f)(jnp.ones((8, 3), jnp.float32), jnp.ones(8, bool))
    dtypes = set(_result_dtypes(jaxpr.jaxpr))
    assert np.dtype(np.float32) in dtypes and np.dtype(np.float64) not in dtypes


def test_lhf_invariant_is_scale_free_bitwise(dtype):
    """gamma(2^k s) == gamma(s) bitwise, also where float32 squares would under- or overflow."""
    sig = np.r_[np.zeros((1, 3)), np.random.default_rng(19).normal(size=(9, 3))]
    gamma = jax.jit(lambda s: lhf.gamma(s, jnp.ones(10, bool), lengths=(4, 10)))
    want = np.asarray(gamma(jnp.asarray(sig, dtype)))
    assert want.dtype == dtype and (want > 0).all()
    for k in (-70, -20, 20, 60):
        np.testing.assert_array_equal(gamma(jnp.asarray(np.ldexp(sig, k), dtype)), want)


def test_unit_scale_is_an_exact_power_of_two(dtype):
    unit_scale = _common.unit_scale
    sig = np.random.default_rng(20).normal(size=(8, 3)).astype(dtype)
    for k in (-100, -30, 0, 30, 100):
        s = np.ldexp(sig, k).astype(dtype)
        out = np.asarray(unit_scale(jnp.asarray(s)))
        assert out.dtype == dtype and 0.5 <= np.abs(out).max() < 1
        e = np.unique(np.frexp(out / s)[1])
        assert len(e) == 1
        np.testing.assert_array_equal(out, np.ldexp(s, int(e[0]) - 1))  # one exact power of two
    assert not np.asarray(unit_scale(jnp.zeros((8, 3), dtype))).any()
    tiny = np.full((8, 3), np.finfo(dtype).smallest_subnormal, dtype)  # scaled or flushed to 0, never inf
    assert np.isfinite(np.asarray(unit_scale(jnp.asarray(tiny)))).all()


def test_centred_entries_are_the_scatter_of_the_valid_rows(dtype):
    x = np.random.default_rng(21).normal(size=(16, 3)) + 5.0
    valid = np.arange(16) < 11
    for mask in (None, valid):
        rows = x if mask is None else x[mask]
        want_mean = rows.mean(axis=0)
        want = (rows - want_mean).T @ (rows - want_mean)
        xin = np.where(valid[:, None], x, 1e6) if mask is not None else x  # padding rows take no part
        mean, entries = jax.jit(_common.centred_entries)(
            jnp.asarray(xin, dtype), None if mask is None else jnp.asarray(mask))
        assert all(np.asarray(v).dtype == dtype for v in (*mean, *entries))
        np.testing.assert_allclose(np.asarray(mean), want_mean, rtol=TOL[dtype])
        np.testing.assert_allclose(np.asarray(entries), [want[i, j] for i, j in _common.PAIRS],
                                   rtol=TOL[dtype], atol=TOL[dtype] * np.abs(want).max())
    mean, entries = _common.centred_entries(jnp.ones((4, 3), dtype), jnp.zeros(4, bool))  # no valid row
    assert not np.asarray(mean).any() and not np.asarray(entries).any()


def test_voxel_frame_derivative_is_perturbation_theory_and_finite_where_degenerate():
    rng = np.random.default_rng(22)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    cov, dcov = q @ np.diag([1.0, 2.0, 4.0]) @ q.T, rng.normal(size=(3, 3))
    dcov = dcov + dcov.T

    def entries(m):
        return tuple(jnp.asarray(m[i, j]) for i, j in _common.PAIRS)

    v, dv = jax.jit(lambda e, d: jax.jvp(cubic_kernel.frame, (e,), (d,)))(entries(cov), entries(dcov))
    eps = 1e-6
    plus, minus = (np.asarray(cubic_kernel.frame(entries(cov + s * eps * dcov))) for s in (1, -1))
    np.testing.assert_allclose(np.asarray(dv), (plus - minus) / (2 * eps), atol=1e-6)
    np.testing.assert_allclose(np.asarray(v).T @ np.asarray(v), np.eye(3), atol=1e-12)
    for flat in (np.diag([0.0, 1.0, 1.0]), np.eye(3), np.zeros((3, 3))):  # equal eigenvalues: no derivative across
        _, dv = jax.jvp(cubic_kernel.frame, (entries(flat),), (entries(dcov),))
        assert np.isfinite(np.asarray(dv)).all()


def test_lhf_isotropic_signal_has_a_three_dimensional_eigenspace():
    sig = _isotropic_signal(np.random.default_rng(14))
    lam, _, _ = _spectrum(sig)
    tol = 8 * len(sig) * np.finfo(np.float64).eps
    assert [len(g) for g in naive.eigenspaces(lam, tol)] == [4, 3]


def test_lhf_invariant_is_the_reference_l1_averaged_over_rotations_and_random_bases():
    """gamma = E[L1 high] / E[L1 total] of Eq. (14) over Haar-random rotations of the signal and
    Haar-random bases of every eigenspace of R."""
    rng = np.random.default_rng(15)
    m = 20000
    for sig in (np.r_[np.zeros((1, 3)), rng.normal(size=(9, 3))], _isotropic_signal(rng)):
        lam, v, t = _spectrum(sig)
        lam = lam / lam.max()
        vr = np.repeat(v[None], m, axis=0)  # (m, n, n)
        for g in naive.eigenspaces(lam, 1e-9):
            q, r = np.linalg.qr(rng.normal(size=(m, len(g), len(g))))
            q = q * np.sign(np.diagonal(r, axis1=1, axis2=2))[:, None, :]  # Haar: fix QR's signs
            vr[:, :, g] = vr[:, :, g] @ q
        turned = sig @ Rotation.random(m, random_state=rng).as_matrix()  # (m, n, 3)
        a = np.abs(np.swapaxes(vr, 1, 2) @ turned).sum(axis=2)  # (m, n) L1 per coefficient row
        high, total = a[:, :t].sum(axis=1), a.sum(axis=1)
        assert high.mean() / total.mean() == pytest.approx(_lhf_kernel(sig), rel=3e-3)
        assert (high / total).std() > 1e-3  # a single basis does change the reference ratio


def test_jit_equals_eager_per_neighbourhood():
    p = uniform_cloud(60, seed=9)
    offsets, valid = jnp.asarray(p[hgjax.knn(p, 8).idx[0]] - p[0]), jnp.ones(8, bool)
    fn = functools.partial(lhf.gamma, lengths=(5, 8))
    # XLA may contract products and sums into FMAs under jit (the Gram's y = s Q already
    # differs in the last bit): agree to rounding.
    np.testing.assert_allclose(jax.jit(fn)(offsets, valid), fn(offsets, valid), rtol=1e-14)
    row = hgjax.cube(p, 0.3).idx[0]
    valid = jnp.asarray(row < 60)
    offsets = jnp.asarray(np.where(row[:, None] < 60, np.r_[p, np.zeros((1, 3))][row] - p[0], 0))
    np.testing.assert_allclose(jax.jit(hkc.beta)(offsets, valid, 0.2), hkc.beta(offsets, valid, 0.2), rtol=1e-14)
    assert 0 < float(hkc.beta(offsets, valid, 0.2)) < np.inf


def test_vmap_equals_loop_per_neighbourhood():
    p = uniform_cloud(40, seed=10)
    offsets = jnp.asarray(p[hgjax.knn(p, 6).idx] - p[:, None, :])
    valid = jnp.ones(6, bool)
    fn = functools.partial(lhf.gamma, lengths=(6,))
    batched = jax.vmap(fn, in_axes=(0, None))(offsets, valid)
    looped = jnp.stack([fn(offsets[i], valid) for i in range(40)])
    np.testing.assert_allclose(batched, looped, rtol=1e-13)


def test_hkc_reference_d_factor_and_hkf_invariant_is_beta_over_one_plus_beta():
    p = uniform_cloud(300, seed=11)
    res = naive.resolution(p)
    beta = host_score(p, "hkc", resolution=res, d_factor=D_FACTOR)
    # The reference variant's default d factor is 1.3 (REFERENCE.md).
    np.testing.assert_array_equal(host_score(p, "hkc", variant="reference"),
                                  host_score(p, "hkc", variant="reference", resolution=res, d_factor=1.3))
    assert not np.array_equal(host_score(p, "hkc", variant="reference"), beta)
    sigma = host_score(p, "hkf", resolution=res, d_factor=D_FACTOR)
    with np.errstate(invalid="ignore"):
        want = np.where(np.isinf(beta), 1, beta / (1 + beta))
    np.testing.assert_allclose(sigma, want, rtol=1e-12)
    assert np.isfinite(beta).any() and not np.allclose(want, want[0])


def test_kernel_band_energies_turn_with_axis_permutations_not_sign_flips():
    """The paper's low band (row-centred along (1, 1, 1)) is invariant under permutations of the
    kernel's axes but not under sign flips; the invariant energies are its average over the 8 flips."""
    c = cubic_kernel.integer_offsets(3)
    where = {tuple(x): j for j, x in enumerate(c)}
    rng = np.random.default_rng(23)
    changed = False
    for _ in range(5):
        s = rng.integers(0, 4, size=27).astype(np.float64)
        ref = lambda m: np.asarray(cubic_kernel.band_energies(jnp.asarray(s[[where[tuple(x @ m)] for x in c]]), 3,  # noqa: E731
                                                       "reference"))
        base = ref(np.eye(3))
        for perm in ([1, 2, 0], [1, 0, 2], [2, 1, 0]):
            np.testing.assert_allclose(ref(np.eye(3)[perm]), base, rtol=1e-12)
        flips = np.array([ref(np.diag(f)) for f in itertools.product((1.0, -1.0), repeat=3)])
        changed |= np.ptp(flips[:, 1]) > 1e-3  # a flip changes the low band (unless C^T s lies on an axis)
        np.testing.assert_allclose(np.asarray(cubic_kernel.band_energies(jnp.asarray(s), 3, "invariant")),
                                   flips.mean(axis=0), rtol=1e-12)
    assert changed


@pytest.mark.full
@pytest.mark.parametrize("method", ["hkc", "hkf"])
def test_hkc_hkf_default_is_rotation_translation_and_scale_invariant(method, dtype):
    """Default HKC/HKF scores of a noisy box union under a random similarity: equal to rounding
    (a point whose neighbour lies within rounding of a voxel face may change one count), the kept
    set unchanged; the reference variant's axis-aligned cube does change."""
    p = hgjax.eval.box_union_cloud(seed=3, n_points=4000, noise=0.1).points.astype(dtype)
    rot = Rotation.random(random_state=np.random.default_rng(22)).as_matrix()
    q = (3.7 * p.astype(np.float64) @ rot.T + [5.0, -2.0, 1.0]).astype(dtype)
    a, b = host_score(p, method), host_score(q, method)
    same = np.isclose(a, b, rtol=1e-4 if dtype == np.float32 else 1e-9, atol=0) | (np.isinf(a) & np.isinf(b))
    assert same.mean() >= 0.99
    kept_a, kept_b = (hgjax.keep(x, 0.2, method=method) for x in (a, b))  # resample's kept sets
    assert len(np.intersect1d(kept_a, kept_b)) / len(kept_a) >= 0.99
    ref_a, ref_b = (hgjax.resample(x, 0.2, method=method, variant="reference") for x in (p, q))
    assert len(np.intersect1d(ref_a, ref_b)) / len(ref_a) < 0.9


def test_scores_keep_float32():
    p = uniform_cloud(100).astype(np.float32)
    for fn in FAST.values():
        assert fn(p).dtype == np.float32
