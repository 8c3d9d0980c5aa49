"""Differentiable soft resampling: soft_score, soft_select, soft_weights, soft_resample.

Gradients with respect to nb.points (a new hgjax.Neighbourhoods(points, nb.idx, nb.scale) inside
the differentiated function) and the float parameters (tau, ratio, temperature); soft -> hard
limits; validation.
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

import fixtures
import hgjax
from hgjax.scores import hkc, lhf, cubic_kernel

METHODS = sorted(m for m, e in hgjax.METHODS.items() if isinstance(e, hgjax.Method))
TAU_METHODS = ("hkc", "hkf", "lhf")  # soft scores with a tau
N = 160
RATIO = 0.25  # RATIO * N is an integer: the hard top-k keeps exactly that many
BOX = (3.0, 2.0, 1.5)  # the sides of the box whose surface the clouds sample
CAPACITY = 128  # fixed K: one compilation serves every cloud of a method (GFR rows hold ~100)


def floats_of(method, tau=0.1, temperature=0.05):
    """The traced float parameters of soft_weights for a method."""
    return {"ratio": RATIO, "temperature": temperature, **({"tau": tau} if method in TAU_METHODS else {})}


def weights_of(points, nb, method, floats):
    """soft_weights with nb.points replaced by ``points`` (differentiable in both)."""
    nb = hgjax.Neighbourhoods(points, nb.idx, nb.scale)
    return hgjax.soft_weights(nb, floats["ratio"], method=method, **{k: v for k, v in floats.items() if k != "ratio"})


@functools.lru_cache(maxsize=None)
def setup(method, seed=0, noise=0.01):
    pts = fixtures.box_surface(N, seed, noise=noise, size=BOX)
    return pts, hgjax.neighbourhoods(pts, method)


# ------------------------------------------------------------------------- soft_select


@pytest.mark.parametrize("largest", [True, False])
@pytest.mark.parametrize("ratio", [0.1, 0.93])
def test_soft_select_range_and_sum(dtype, ratio, largest):
    s = np.random.default_rng(1).standard_normal(500).astype(dtype)
    w = hgjax.soft_select(s, ratio, temperature=0.3, largest=largest)
    assert w.dtype == dtype
    assert bool(((w >= 0) & (w <= 1)).all())
    np.testing.assert_allclose(float(w.sum()), ratio * 500, rtol=1e-4 if dtype == np.float32 else 1e-9)
    # Monotone in the score, in the requested direction.
    order = np.argsort(s)
    dw = np.diff(np.asarray(w)[order])
    assert (dw >= -1e-6).all() if largest else (dw <= 1e-6).all()


@pytest.mark.parametrize("largest", [True, False])
def test_soft_select_low_temperature_is_top_k(largest):
    s = np.random.default_rng(2).random(400)
    w = np.asarray(hgjax.soft_select(s, RATIO, temperature=1e-7, largest=largest))
    mask = np.zeros(400, bool)
    mask[hgjax.top_k(s, 100, largest=largest)] = True
    np.testing.assert_allclose(w, mask, atol=1e-6)


def test_soft_select_implicit_gradients():
    s = jnp.asarray(np.random.default_rng(3).standard_normal(50))
    f = jax.jit(lambda s, t, r: hgjax.soft_select(s, r, temperature=t))
    check_grads(f, (s, 0.4, 0.3), order=1, modes=("fwd", "rev"))
    # The total is fixed, so its gradient with respect to every input is 0.
    g = jax.grad(lambda s, t: jnp.sum(f(s, t, 0.3)), argnums=(0, 1))(s, 0.4)
    np.testing.assert_allclose(g[0], 0, atol=1e-12)
    np.testing.assert_allclose(g[1], 0, atol=1e-12)
    # d sum / d ratio = N.
    np.testing.assert_allclose(jax.grad(lambda r: jnp.sum(f(s, 0.4, r)))(0.3), 50, rtol=1e-9)


def test_soft_select_rejects_matrix():
    with pytest.raises(ValueError, match="scores must have shape"):
        hgjax.soft_select(np.zeros((3, 2)), 0.5)


# ------------------------------------------------------------------------- smooth scores


def test_soft_hkf_is_soft_hkc():
    _, nb = setup("hkc")
    np.testing.assert_array_equal(hgjax.soft_score(nb, "hkf"), hgjax.soft_score(nb, "hkc"))


@pytest.mark.full
@pytest.mark.parametrize("method", [m for m in METHODS if m not in ("hkf", "pca_ac")])  # = hkc, ea
def test_check_grads_scores(method):
    pts = fixtures.box_surface(48, 0, noise=0.01, size=BOX)
    nb = hgjax.neighbourhoods(pts, method)
    if method in TAU_METHODS:
        f = lambda p, tau: hgjax.soft_score(hgjax.Neighbourhoods(p, nb.idx, nb.scale), method, tau=tau)  # noqa: E731
        args = (pts, 0.3)
    else:
        f, args = (lambda p: hgjax.soft_score(hgjax.Neighbourhoods(p, nb.idx, nb.scale), method)), (pts,)
    # LHF's weight eps (Eq. (16)) is an order statistic of the gammas, smooth only piecewise:
    # a step of 1e-6 does not cross one of its kinks on this cloud.
    check_grads(jax.jit(f), args, order=1, modes=("fwd", "rev"), eps=1e-6)


@pytest.mark.full
def test_check_grads_weights():
    pts, nb = setup("ea")
    f = jax.jit(lambda p, t, r: weights_of(p, nb, "ea", {"ratio": r, "temperature": t}))
    check_grads(f, (jnp.asarray(pts), 0.01, RATIO), order=1, modes=("fwd", "rev"), eps=1e-6)


DEGENERATE = fixtures.degenerate_clouds()  # every cloud has the same N: one compilation per method
N_DEGENERATE = len(DEGENERATE["all_equal"])


@functools.lru_cache(maxsize=None)
def value_and_grads(method):
    c = jnp.asarray(np.random.default_rng(8).random(N_DEGENERATE))
    loss = lambda p, nb, floats: jnp.sum(c * weights_of(p, nb, method, floats))  # noqa: E731
    return jax.jit(jax.value_and_grad(loss, argnums=(0, 2)))


@pytest.mark.full
@pytest.mark.parametrize("method", METHODS)
def test_gradients_finite_on_degenerate_clouds(method):
    for case, pts in DEGENERATE.items():
        nb = hgjax.neighbourhoods(pts, method, capacity=CAPACITY)
        value, (g_points, g_floats) = value_and_grads(method)(jnp.asarray(pts), nb, floats_of(method))
        assert np.isfinite(value), case
        assert np.isfinite(np.asarray(g_points)).all(), case
        assert all(np.isfinite(float(g)) for g in g_floats.values()), (case, g_floats)
        assert set(g_floats) == set(floats_of(method))
    # On a generic cloud the gradients are not all zero (the test above could not pass vacuously).
    pts = fixtures.box_surface(N_DEGENERATE, 3, noise=0.01, size=BOX)
    nb = hgjax.neighbourhoods(pts, method, capacity=CAPACITY)
    _, (g_points, g_floats) = value_and_grads(method)(jnp.asarray(pts), nb, floats_of(method))
    assert float(jnp.abs(g_points).max()) > 0 and float(g_floats["ratio"]) != 0


def spectral_signal(eigenvalues, seed=14, n=7):
    """(n, 3) LHF signal (first row the point itself, 0) whose centred rows have covariance
    eigenvalues ``eigenvalues`` and a non-zero centroid offset."""
    y = np.random.default_rng(seed).normal(size=(n, 3))
    q, _ = np.linalg.qr(y - y.mean(axis=0))  # orthonormal columns, orthogonal to 1
    y = q * np.sqrt(np.asarray(eigenvalues))
    return y - y[0]


# mu = (0.01, 0.505, 1): the last two steps of lam, 0.495 and 0.495, tie: the band threshold
# (and the hard gamma) jumps there.
TIE = (0.01, 0.505, 1.0)


def soft_gamma(s, tau):
    """Smooth invariant gamma of one signal s (n, 3), first row the point itself (0)."""
    n = s.shape[0]
    return lhf.soft_gamma(s, jnp.ones(n, bool), tau, lengths=(n,))[0]


def hard_gamma(s):
    n = s.shape[0]
    return lhf.gamma(s, jnp.ones(n, bool), lengths=(n,))[0]


@pytest.mark.full
def test_soft_lhf_is_continuous_where_the_hard_one_jumps_at_the_band_threshold():
    """Two steps of lam tie: the hard gamma switches band, the soft one blends."""
    below, above = (jnp.asarray(spectral_signal((0.01, m, 1.0))) for m in (0.505 - 1e-9, 0.505 + 1e-9))
    hard_jump = abs(float(hard_gamma(above)) - float(hard_gamma(below)))
    assert hard_jump > 0.1
    assert float(soft_gamma(below, 1e-12)) == pytest.approx(float(hard_gamma(below)), rel=1e-12)
    s = jnp.asarray(spectral_signal(TIE))
    soft_steps = [abs(float(soft_gamma(jnp.asarray(spectral_signal((0.01, 0.505 + e, 1.0))), 0.1))
                      - float(soft_gamma(s, 0.1))) for e in (1e-3, 1e-6, 1e-9)]
    assert soft_steps == sorted(soft_steps, reverse=True) and soft_steps[-1] < 1e-8


@pytest.mark.full
def test_soft_lhf_gradients_are_exact_at_and_near_the_band_threshold():
    d = jnp.asarray(np.random.default_rng(16).normal(size=(7, 3))).at[0].set(0)
    f = jax.jit(soft_gamma)
    for mu in (TIE, (0.2, 0.6, 1.0)):
        s = jnp.asarray(spectral_signal(mu))
        for e in (0.0, 1e-9, 1e-6, 1e-3, 0.3):
            check_grads(lambda x: f(x, 0.1), (s + e * d,), order=1, modes=("fwd", "rev"), eps=1e-6)


def test_soft_lhf_gradients_are_finite_where_eigenvalues_cross():
    """Where two eigenvalues of C are equal gamma is Lipschitz, not differentiable: finite gradients."""
    grad = jax.jit(jax.grad(soft_gamma))
    for mu in ((0.3, 1.0, 1.0), (0.5, 0.5, 1.0), (1.0, 1.0, 1.0)):
        g = np.asarray(grad(jnp.asarray(spectral_signal(mu)), 0.1))
        assert np.isfinite(g).all() and np.abs(g).max() > 0


@pytest.mark.full
def test_soft_lhf_jvp_under_jit_equals_eager_near_the_band_threshold():
    """Compiled and op-by-op JVPs agree in 20 directions at 6 distances to the tie (one batch of 120)."""
    s = jnp.asarray(spectral_signal(TIE))
    t = jnp.asarray(np.random.default_rng(18).normal(size=s.shape))
    d = np.stack([np.random.default_rng(seed).normal(size=s.shape) for seed in range(20)])
    d[:, 0] = 0
    e = np.array([1e-9, 1e-6, 1e-4, 1e-3, 1e-2, 0.3])
    x = jnp.asarray(np.asarray(s) + (e[None, :, None, None] * d[:, None]).reshape(-1, *s.shape))  # (120, 7, 3)

    def jvp(x):
        return jax.jvp(lambda x: soft_gamma(x, 0.1), (x,), (t,))[1]

    np.testing.assert_allclose(jax.jit(jax.vmap(jvp))(x), jax.vmap(jvp)(x), rtol=1e-9, atol=1e-9)


@pytest.mark.full
def test_soft_lhf_gradients_finite_on_degenerate_signals(dtype):
    """Symmetric, empty, collinear, duplicate and near-isotropic signals at tiny and huge scales."""
    rng = np.random.default_rng(17)
    line = np.outer(np.r_[0, rng.random(7)], [1.0, 2.0, 3.0])
    sym = np.array([[0, 0, 0], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1], [1, 1, 1.0]])
    near_iso = spectral_signal((1.0, 1.0, 1.0), n=8) + 1e-6 * np.r_[np.zeros((1, 3)), rng.normal(size=(7, 3))]
    dup = np.repeat(np.r_[np.zeros((1, 3)), rng.random((3, 3))], 2, axis=0)
    signals = np.stack([line, sym, near_iso, dup, np.zeros((8, 3))])
    grad = jax.jit(jax.vmap(jax.grad(soft_gamma), in_axes=(0, None)))
    for scale in (1e-12, 1e-6, 1.0, 1e6, 1e12):
        g = grad(jnp.asarray(scale * signals, dtype), jnp.asarray(0.1, dtype))
        assert g.dtype == dtype
        assert np.isfinite(np.asarray(g)).all(), scale
        assert float(jnp.abs(g[2]).max()) > 0  # not frozen: the near-isotropic signal has a gradient


@pytest.mark.full
def test_soft_lhf_at_low_tau_is_the_hard_kernel_on_degenerate_signals():
    for p in (fixtures.uniform_cloud(40, seed=18), *(DEGENERATE[c] for c in ("collinear", "coplanar", "duplicates"))):
        idx = hgjax.knn(p, 8).idx
        sig = jnp.asarray(p[idx] - p[:, None, :])  # (N, 8, 3)
        np.testing.assert_allclose(jax.vmap(soft_gamma, in_axes=(0, None))(sig, 1e-12), jax.vmap(hard_gamma)(sig),
                                   rtol=1e-12, atol=1e-14)


# ------------------------------------------------------------------------- tau -> 0


def jittered_lattice(seed, jitter=0.08):
    """Box-surface lattice points (spacing 1) jittered a little: per-axis offsets stay
    within 2 * jitter of an integer, far from the voxel faces at half-integers (d = 1)."""
    shell = fixtures.lattice_shell(7)
    return shell + jitter * np.random.default_rng(seed).uniform(-1, 1, shell.shape)


def lattice_neighbourhoods(seed):
    """Reference HKC neighbourhoods (axis-aligned kernel, which keeps the lattice off the voxel
    faces) of a jittered lattice with d = 1 exactly."""
    return hgjax.neighbourhoods(jittered_lattice(seed), "hkc", variant="reference", resolution=1.0, d_factor=1.0)


@pytest.mark.full
def test_soft_counts_converge_to_hard_counts():
    nb = lattice_neighbourhoods(0)
    offsets = jnp.asarray(np.where(nb.mask[..., None], np.r_[nb.points, np.zeros((1, 3))][nb.idx] - nb.points[:, None], 0))
    valid = jnp.asarray(nb.mask)
    hard = jax.vmap(lambda o, v: cubic_kernel.local_signal(o, v, 1.0, 3))(offsets, valid)
    errors = []
    for tau in (0.3, 0.1, 0.03, 0.01):
        soft = jax.vmap(lambda o, v: cubic_kernel.soft_local_signal(o, v, 1.0, tau, 3))(offsets, valid)
        errors.append(float(jnp.max(jnp.abs(soft - hard))))
    assert errors == sorted(errors, reverse=True)
    assert errors[-1] < 1e-12 and errors[0] > 1e-3


@pytest.mark.full
def test_soft_hkc_converges_to_beta_over_one_plus_beta():
    nb = lattice_neighbourhoods(1)
    beta = np.asarray(hgjax.score(nb, "hkc"))
    with np.errstate(invalid="ignore"):
        sigma = np.where(np.isinf(beta), 1.0, beta / (1 + beta))
    errors = [float(np.max(np.abs(np.asarray(hgjax.soft_score(nb, "hkc", tau=tau)) - sigma)))
              for tau in (0.3, 0.1, 0.01)]
    assert errors == sorted(errors, reverse=True) and errors[-1] < 1e-9
    soft_sigma = np.asarray(hgjax.soft_score(nb, "hkc", tau=0.01))
    finite = np.isfinite(beta)
    assert finite.any() and (~finite).any()
    np.testing.assert_allclose(soft_sigma[finite] / (1 - soft_sigma[finite]), beta[finite], rtol=1e-8)
    assert (soft_sigma[~finite] > 1 - 1e-9).all()  # beta = inf  <->  sigma = 1
    # The per-neighbourhood kernels directly: soft_beta -> beta / (1 + beta).
    o = jnp.array([[0.0, 0, 0], [1.02, 0, 0], [0, 0.97, 0]])
    b = float(hkc.beta(o, jnp.ones(3, bool), 1.0))
    assert 0 < b < np.inf
    assert float(hkc.soft_beta(o, jnp.ones(3, bool), 1.0, 1e-3)) == pytest.approx(b / (1 + b), rel=1e-9)


def test_soft_lhf_converges_to_hard_lhf():
    pts = fixtures.box_surface(N, 2, noise=0.02, size=BOX)
    nb = hgjax.neighbourhoods(pts, "lhf")
    hard = np.asarray(hgjax.score(nb, "lhf"))
    far = np.asarray(hgjax.soft_score(nb, "lhf", tau=1e-9))
    np.testing.assert_allclose(far, hard, atol=1e-9)
    blurred = np.asarray(hgjax.soft_score(nb, "lhf", tau=0.3))
    assert np.abs(blurred - hard).max() > 1e-3


@pytest.mark.parametrize("method", ["ea", "pca_ac"])
def test_soft_ea_equals_hard_ea(method):
    _, nb = setup(method)
    np.testing.assert_allclose(hgjax.soft_score(nb, method), hgjax.score(nb, method), rtol=1e-9, atol=1e-12)


# ------------------------------------------------------------------------- soft -> hard


@pytest.mark.full
@pytest.mark.parametrize("method", METHODS)
def test_low_temperature_support_matches_hard_selection(method):
    pts, nb = setup(method)
    m = round(RATIO * N)
    if method == "gfr":  # GFR's hard selection samples; its deterministic mode keeps the top scores
        hard = hgjax.keep(hgjax.score(nb, method), RATIO, method=method, mode="top")
    else:
        hard = hgjax.keep(hgjax.score(nb, method), RATIO, method=method)
    w = np.asarray(weights_of(nb.points, nb, method, floats_of(method, tau=1e-4, temperature=1e-6)))
    support = np.flatnonzero(w > 0.5)
    overlap = np.intersect1d(support, hard).size / m
    assert overlap >= 0.95, overlap
    assert abs(support.size - m) <= 0.05 * m


# ------------------------------------------------------------------------- jit boundary, dtype, scale


def test_soft_resample_is_soft_weights_of_neighbourhoods_and_rejects_tracers():
    pts = fixtures.box_surface(N, 20, noise=0.01, size=BOX)
    nb = hgjax.neighbourhoods(pts, "hkc")
    np.testing.assert_array_equal(hgjax.soft_resample(pts, RATIO, method="hkc", tau=0.2),
                                  hgjax.soft_weights(nb, RATIO, method="hkc", tau=0.2))
    with pytest.raises(TypeError, match=r"neighbourhoods.*soft_weights"):
        jax.jit(lambda p: hgjax.soft_resample(p, RATIO))(pts)
    with pytest.raises(TypeError, match=r"neighbourhoods.*soft_weights"):
        jax.grad(lambda p: hgjax.soft_resample(p, RATIO).sum())(pts)


def test_keeps_float32():
    pts = fixtures.box_surface(N, 0, noise=0.01, size=BOX).astype(np.float32)
    for method in ("hkc", "ea"):
        w = weights_of(*(lambda nb: (nb.points, nb))(hgjax.neighbourhoods(pts, method)), method, floats_of(method))
        assert w.dtype == np.float32, method
        np.testing.assert_allclose(float(w.sum()), RATIO * N, rtol=1e-4)


@pytest.mark.full
@pytest.mark.parametrize("method", METHODS)
def test_soft_weights_are_scale_free(method):
    """Clouds scaled by 1e-8 (float32) and by 1e3 give the unit cloud's soft weights
    (soft_resample's, which are soft_weights of the neighbourhoods: one compilation per dtype)."""
    pts = fixtures.box_surface(96, 9, noise=0.01, size=BOX)
    weights = jax.jit(lambda nb: hgjax.soft_weights(nb, RATIO, method=method))
    want, tiny, big = (np.asarray(weights(hgjax.neighbourhoods(p, method)))
                       for p in (pts, (pts * 1e-8).astype(np.float32), pts * 1e3))
    np.testing.assert_allclose(big, want, atol=1e-6)
    np.testing.assert_allclose(tiny, want, atol=2e-3)


@pytest.mark.parametrize("method", ["hkc", "hkf"])
def test_soft_hkc_hkf_on_all_duplicate_cloud(method):
    pts = np.tile([[0.3, -1.0, 2.0]], (40, 1))
    w = np.asarray(hgjax.soft_resample(pts, RATIO, method=method))
    assert np.isfinite(w).all()
    np.testing.assert_allclose(w, RATIO, rtol=1e-6)  # every point alike: equal weights


# ------------------------------------------------------------------------- errors


@pytest.mark.parametrize("name", ["tau", "temperature"])
@pytest.mark.parametrize("value", [float("nan"), 0.0, -0.1])
def test_bad_tau_and_temperature_raise_value_error_naming_them(name, value):
    pts, nb = setup("hkc")
    for call in (lambda: hgjax.soft_weights(nb, RATIO, method="hkc", **{name: value}),
                 lambda: hgjax.soft_resample(pts, RATIO, method="hkc", **{name: value}),
                 lambda: jax.jit(lambda nb: hgjax.soft_weights(nb, RATIO, method="hkc", **{name: value}))(nb)):
        with pytest.raises(ValueError, match=name):
            call()
    if name == "tau":
        with pytest.raises(ValueError, match="tau"):
            hgjax.soft_score(hgjax.neighbourhoods(pts, "lhf"), "lhf", tau=value)


@pytest.mark.parametrize("method", METHODS)
def test_soft_resample_rejects_nan_points_and_too_few_points(method):
    pts = fixtures.box_surface(40, 0, noise=0.01, size=BOX)
    bad = pts.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match="points"):
        hgjax.soft_resample(bad, RATIO, method=method)
    if method != "gfr":  # GFR's radius graph has no minimum size
        with pytest.raises(ValueError, match="points"):
            hgjax.soft_resample(pts[:1], RATIO, method=method, **({"k": 40} if method in ("ea", "pca_ac") else {}))


def test_errors():
    _, nb = setup("hkc")
    with pytest.raises(ValueError, match="unknown method 'nope'"):
        hgjax.soft_weights(nb, RATIO, method="nope")
    with pytest.raises(ValueError, match="nb.scale"):
        hgjax.soft_score(hgjax.Neighbourhoods(nb.points, nb.idx), "hkc")
    with pytest.raises(TypeError, match="soft_score takes no ratio"):
        hgjax.soft_score(setup("lhf")[1], "lhf", ratio=RATIO)
    with pytest.raises(ValueError, match="ratio must be in"):
        hgjax.soft_weights(nb, 1.5, method="hkc")
    with pytest.raises(TypeError, match="bogus"):
        hgjax.soft_score(nb, "hkc", bogus=1)


BAD_RATIOS = [1.5, 0.0, -0.2, float("nan")]
RATIO_ENTRIES = {  # every traced entry that takes a ratio; LHF's goes through its kept count first
    "soft_weights": lambda nb, r: hgjax.soft_weights(nb, r, method="ea"),
    "soft_weights-lhf": lambda nb, r: hgjax.soft_weights(nb, r, method="lhf"),
    "soft_select": lambda nb, r: hgjax.soft_select(nb.points[:, 0], r),
}


def _ratio_message(ratio):
    return rf"ratio must be in \(0, 1\]; got {ratio}"


@pytest.mark.parametrize("ratio", BAD_RATIOS)
@pytest.mark.parametrize("entry", RATIO_ENTRIES)
def test_a_concrete_ratio_out_of_range_raises_value_error_naming_it(entry, ratio):
    nb = setup("lhf" if entry.endswith("lhf") else "ea")[1]
    with pytest.raises(ValueError, match=_ratio_message(ratio)):
        RATIO_ENTRIES[entry](nb, ratio)


@pytest.mark.full
@pytest.mark.parametrize("ratio", BAD_RATIOS)
@pytest.mark.parametrize("transform", ["jit", "vmap", "grad"])
@pytest.mark.parametrize("entry", RATIO_ENTRIES)
def test_a_traced_ratio_out_of_range_stops_the_program_naming_it(entry, transform, ratio):
    nb = setup("lhf" if entry.endswith("lhf") else "ea")[1]
    f = functools.partial(RATIO_ENTRIES[entry], nb)
    traced = {"jit": jax.jit(f),
              "vmap": jax.jit(lambda r: jax.vmap(f)(jnp.stack([jnp.float32(RATIO), r]))),
              "grad": jax.jit(jax.grad(lambda r: f(r).sum()))}[transform]
    good = np.asarray(traced(jnp.float32(RATIO)))
    assert np.isfinite(good).all()
    with pytest.raises(jax.errors.JaxRuntimeError, match=_ratio_message(ratio)):
        np.asarray(traced(jnp.float32(ratio)))


def test_a_traced_ratio_gives_the_concrete_ratio_weights():
    _, nb = setup("ea")
    np.testing.assert_array_equal(jax.jit(lambda r: hgjax.soft_weights(nb, r, method="ea"))(RATIO),
                                  jax.jit(lambda: hgjax.soft_weights(nb, RATIO, method="ea"))())


def test_a_traced_ratio_must_be_a_scalar_number():
    _, nb = setup("ea")
    with pytest.raises(ValueError, match=r"ratio must be a scalar in \(0, 1\]; got a tracer of shape \(2,\)"):
        jax.jit(lambda r: hgjax.soft_weights(nb, r, method="ea"))(jnp.array([0.2, 0.3]))
    with pytest.raises(TypeError, match="ratio must be a number"):
        jax.jit(lambda r: hgjax.soft_weights(nb, r, method="ea"))(jnp.array(True))


@pytest.mark.parametrize("entry", ["resample", "soft_resample", "keep"])
def test_a_ratio_that_sets_the_count_kept_refuses_a_tracer(entry):
    pts, nb = setup("ea")
    call = {"resample": lambda r: hgjax.resample(pts, r, method="ea", search="jax"),
            "soft_resample": lambda r: hgjax.soft_resample(pts, r, method="ea"),
            "keep": lambda r: hgjax.keep(pts[:, 0], r, method="ea")}[entry]
    with pytest.raises(TypeError, match=r"ratio must be concrete here: it sets the number of points kept"):
        jax.jit(call)(RATIO)
