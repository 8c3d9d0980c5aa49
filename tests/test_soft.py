"""Differentiable soft resampling (hgjax.soft): smooth scores, soft top-k, gradients."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

import hgjax
from hgjax import soft
from hgjax.scores import voxel

METHODS = sorted(soft.SOFT_METHODS)
DISTINCT = [m for m in METHODS if m != "hkf"]  # soft "hkf" is the same function as soft "hkc"
N = 160
RATIO = 0.25  # RATIO * N is an integer: the hard top-k keeps exactly that many


def box_surface(seed, n, noise=0.0, size=(3.0, 2.0, 1.5)):
    """n points uniform on the surface of an axis-aligned box, plus Gaussian noise."""
    rng = np.random.default_rng(seed)
    size = np.asarray(size)
    areas = np.array([size[1] * size[2], size[0] * size[2], size[0] * size[1]])
    axis = rng.choice(3, size=n, p=areas / areas.sum())
    pts = rng.random((n, 3)) * size
    pts[np.arange(n), axis] = rng.integers(0, 2, n) * size[axis]
    return pts + noise * rng.standard_normal((n, 3))


@functools.lru_cache(maxsize=None)
def setup(method, seed=0, noise=0.01):
    pts = box_surface(seed, N, noise)
    idx, d = hgjax.soft_neighbourhoods(pts, method=method)
    return pts, idx, d


@functools.lru_cache(maxsize=None)
def jitted_weights(method):
    return jax.jit(hgjax.soft_weights, static_argnames=("ratio", "method", "kernel_size", "lengths"))


scores = jax.jit(soft.soft_scores, static_argnames=("method", "ratio", "kernel_size", "lengths"))


def weights(method, pts, idx, d, *, temperature=0.05, tau=0.1):
    return jitted_weights(method)(pts, idx, RATIO, method=method, temperature=temperature, tau=tau, d=d)


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
    pts, idx, d = setup("hkc")
    np.testing.assert_array_equal(scores(pts, idx, method="hkf", d=d), scores(pts, idx, method="hkc", d=d))


@pytest.mark.parametrize("method", DISTINCT)
def test_check_grads_scores(method):
    pts, idx, d = setup(method)
    if method in ("hkc", "hkf"):
        f, args = (lambda p, tau, d: soft.soft_scores(p, idx, method=method, d=d, tau=tau)), (pts, 0.3, d)
    else:
        f, args = (lambda p, tau: soft.soft_scores(p, idx, method=method, tau=tau, ratio=RATIO)), (pts, 0.3)
    # LHF's weight eps (Eq. (16)) is an order statistic of the gammas, smooth only piecewise:
    # on this cloud a step of 1e-5 crosses one of its kinks, 1e-6 does not.
    check_grads(jax.jit(f), args, order=1, modes=("fwd", "rev"), eps=1e-6)


def test_check_grads_weights():
    pts, idx, _ = setup("ea")
    f = jax.jit(lambda p, t: hgjax.soft_weights(p, idx, RATIO, method="ea", temperature=t))
    check_grads(f, (jnp.asarray(pts), 0.01), order=1, modes=("fwd", "rev"), eps=1e-6)


def degenerate_clouds(n=144):
    """Degenerate clouds of n points each (one compilation serves them all)."""
    rng = np.random.default_rng(4)
    g = np.stack(np.meshgrid(np.arange(12.0), np.arange(12.0), indexing="ij"), -1).reshape(-1, 2)
    base = box_surface(5, n // 3)
    return {
        "flat": np.c_[g, np.zeros(n)],  # exactly planar grid: symmetric signals, beta = inf
        "line": np.c_[np.arange(float(n)), np.zeros(n), np.zeros(n)],  # collinear
        "dup": np.concatenate([base, base, base]),  # every point three times
        "cluster": np.concatenate([np.zeros((24, 3)), box_surface(6, n - 24)]),  # 24 identical points
        "noisy": box_surface(7, n) + 0.2 * rng.standard_normal((n, 3)),
    }


@pytest.mark.parametrize("method", DISTINCT)
def test_gradients_finite_on_degenerate_clouds(method):
    c = np.random.default_rng(8).random(144)

    def loss(p, idx, t, tau, d):
        return jnp.sum(c * hgjax.soft_weights(p, idx, RATIO, method=method, temperature=t, tau=tau, d=d))

    @jax.jit
    def value_grads_tangent(p, idx, d):
        value, grads = jax.value_and_grad(loss, argnums=(0, 2, 3, 4))(p, idx, 0.05, 0.1, d)
        _, tangent = jax.jvp(lambda p: loss(p, idx, 0.05, 0.1, d), (p,), (jnp.ones_like(p),))
        return value, grads, tangent

    for case, pts in degenerate_clouds().items():
        idx, d = hgjax.soft_neighbourhoods(pts, method=method, capacity=256)
        value, grads, tangent = value_grads_tangent(pts, idx, d)
        assert np.isfinite(value) and np.isfinite(tangent), case
        for g in grads:
            assert np.isfinite(np.asarray(g)).all(), case


def isotropic_signal(seed=14):
    """(7, 3) LHF signal with mu1 = mu2 (one 2-D eigenspace of R) and a null-space part."""
    s = np.concatenate([np.zeros((1, 3)), np.eye(3), -np.eye(3)])
    return s + np.r_[0, np.random.default_rng(seed).normal(size=6)][:, None]  # shifts along (1, 1, 1) keep R


def soft_gamma(s, tau):
    n = s.shape[0]
    return soft.soft_lhf_neighbourhood(jnp.zeros(3, s.dtype), s, jnp.ones(n, bool), tau, lengths=(n,))[0]


def hard_gamma(s):
    n = s.shape[0]
    return hgjax.scores.lhf_neighbourhood(jnp.zeros(3, s.dtype), s, jnp.ones(n, bool), lengths=(n,))[0]


def test_soft_lhf_is_continuous_where_the_hard_one_jumps_at_equal_eigenvalues():
    """mu1 = mu2: the hard gamma switches to the 2-D eigenspace's Haar factor, the soft one blends."""
    s = jnp.asarray(isotropic_signal())
    d = jnp.asarray(np.random.default_rng(15).normal(size=s.shape)).at[0].set(0)
    assert float(soft_gamma(s, 1e-9)) == pytest.approx(float(hard_gamma(s)), rel=1e-12)
    hard_jump = abs(float(hard_gamma(s + 1e-9 * d)) - float(hard_gamma(s)))
    soft_steps = [abs(float(soft_gamma(s + e * d, 0.1)) - float(soft_gamma(s, 0.1))) for e in (1e-3, 1e-6, 1e-9)]
    assert hard_jump > 1e-3
    assert soft_steps == sorted(soft_steps, reverse=True) and soft_steps[-1] < 1e-8


def test_soft_lhf_gradients_are_exact_at_and_near_equal_eigenvalues():
    """The eigenvector angle's derivative grows like 1 / (mu2 - mu1); the gradient stays exact."""
    s = jnp.asarray(isotropic_signal())
    d = jnp.asarray(np.random.default_rng(16).normal(size=s.shape)).at[0].set(0)
    f = jax.jit(soft_gamma)
    for e in (0.0, 1e-9, 1e-6, 1e-3, 0.3):
        check_grads(lambda x: f(x, 0.1), (s + e * d,), order=1, modes=("fwd", "rev"), eps=1e-6)


def test_soft_lhf_gradients_finite_on_degenerate_signals(dtype):
    """Symmetric, empty, collinear, duplicate and near-isotropic signals at tiny and huge scales."""
    rng = np.random.default_rng(17)
    line = np.outer(np.r_[0, rng.random(7)], [1.0, 2.0, 3.0])
    sym = np.array([[0, 0, 0], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1], [1, 1, 1.0]])
    near_iso = np.r_[isotropic_signal(), np.zeros((1, 3))] + 1e-6 * np.r_[np.zeros((1, 3)), rng.normal(size=(7, 3))]
    dup = np.repeat(np.r_[np.zeros((1, 3)), rng.random((3, 3))], 2, axis=0)
    signals = np.stack([line, sym, near_iso, dup, np.zeros((8, 3))])
    grad = jax.jit(jax.vmap(jax.grad(soft_gamma), in_axes=(0, None)))
    for scale in (1e-12, 1e-6, 1.0, 1e6, 1e12):
        g = grad(jnp.asarray(scale * signals, dtype), jnp.asarray(0.1, dtype))
        assert g.dtype == dtype
        assert np.isfinite(np.asarray(g)).all(), scale
        assert float(jnp.abs(g[2]).max()) > 0  # not frozen: the near-isotropic signal has a gradient


def test_soft_lhf_at_low_tau_is_the_hard_kernel_on_degenerate_signals():
    rng = np.random.default_rng(18)
    clouds = [rng.random((40, 3)), np.outer(rng.random(40), [1.0, 2.0, 3.0]), np.c_[rng.random((40, 2)), np.zeros(40)],
              np.repeat(rng.random((10, 3)), 4, axis=0)]
    for p in clouds:
        idx = hgjax.knn(p, 8).idx
        sig = jnp.asarray(p[idx] - p[:, None, :])  # (40, 8, 3)
        np.testing.assert_allclose(jax.vmap(soft_gamma, in_axes=(0, None))(sig, 1e-12), jax.vmap(hard_gamma)(sig),
                                   rtol=1e-12, atol=1e-14)


# ------------------------------------------------------------------------- tau -> 0


def jittered_lattice(seed, jitter=0.08):
    """Box-surface lattice points (spacing 1) jittered a little: per-axis offsets stay
    within 2 * jitter of an integer, far from the voxel faces at half-integers (d = 1)."""
    g = np.stack(np.meshgrid(*(np.arange(7.0),) * 3, indexing="ij"), -1).reshape(-1, 3)
    shell = g[(g == 0).any(1) | (g == 6).any(1)]
    return shell + jitter * np.random.default_rng(seed).uniform(-1, 1, shell.shape)


def test_soft_counts_converge_to_hard_counts():
    pts = jittered_lattice(0)
    idx, d = hgjax.soft_neighbourhoods(pts, method="hkc", resolution=1.0, d_factor=1.0, capacity=128)
    ext = np.concatenate([pts, np.zeros((1, 3))])
    hard = jax.vmap(lambda c, nb, v: voxel.local_signal(c, nb, v, d, 3))(pts, ext[idx], idx < len(pts))
    errors = []
    for tau in (0.3, 0.1, 0.03, 0.01):
        f = jax.vmap(lambda c, nb, v: soft.soft_local_signal(c, nb, v, d, tau))
        errors.append(float(jnp.max(jnp.abs(f(pts, ext[idx], idx < len(pts)) - hard))))
    assert errors == sorted(errors, reverse=True)
    assert errors[-1] < 1e-12 and errors[0] > 1e-3


def test_soft_hkc_converges_to_hard_scores():
    pts = jittered_lattice(1)
    idx, d = hgjax.soft_neighbourhoods(pts, method="hkc", resolution=1.0, d_factor=1.0, capacity=128)
    sigma = hgjax.scores.hkf(pts, resolution=1.0, d_factor=1.0)
    beta = hgjax.scores.hkc(pts, resolution=1.0, d_factor=1.0)
    errors = [float(np.max(np.abs(scores(pts, idx, method="hkc", d=d, tau=tau) - sigma)))
              for tau in (0.3, 0.1, 0.01)]
    assert errors == sorted(errors, reverse=True) and errors[-1] < 1e-9
    soft_sigma = np.asarray(scores(pts, idx, method="hkf", d=d, tau=0.01))
    finite = np.isfinite(beta)
    np.testing.assert_allclose(soft_sigma[finite] / (1 - soft_sigma[finite]), beta[finite], rtol=1e-8)
    assert (soft_sigma[~finite] > 1 - 1e-9).all()  # beta = inf  <->  sigma = 1


def test_soft_lhf_converges_to_hard_lhf():
    pts = box_surface(2, N, 0.02)
    idx, _ = hgjax.soft_neighbourhoods(pts, method="lhf")
    hard = hgjax.scores.lhf(pts, ratio=RATIO)
    far = np.asarray(scores(pts, idx, method="lhf", tau=1e-9, ratio=RATIO))
    np.testing.assert_allclose(far, hard, atol=1e-9)
    blurred = np.asarray(scores(pts, idx, method="lhf", tau=0.3, ratio=RATIO))
    assert np.abs(blurred - hard).max() > 1e-3


def test_soft_ea_equals_hard_ea():
    pts, idx, _ = setup("ea")
    np.testing.assert_allclose(scores(pts, idx, method="ea"), hgjax.scores.ea(pts), rtol=1e-9,
                               atol=1e-12)


# ------------------------------------------------------------------------- soft -> hard


@pytest.mark.parametrize("method", METHODS)
def test_low_temperature_support_matches_hard_selection(method):
    pts, idx, d = setup(method)
    m = round(RATIO * N)
    if method in ("hkc", "hkf", "lhf", "ea"):
        hard = hgjax.resample(pts, RATIO, method=method)  # the paper's hard pipeline
    else:  # soft GFR scores the fixed kNN graph, not GFR's radius graph
        hard = hgjax.top_k(np.asarray(scores(pts, idx, method="gfr")), m)
    w = np.asarray(weights(method, pts, idx, d, temperature=1e-6, tau=1e-4))
    support = np.flatnonzero(w > 0.5)
    overlap = np.intersect1d(support, hard).size / m
    assert overlap >= 0.95, overlap
    assert abs(support.size - m) <= 0.05 * m


# ------------------------------------------------------------------------- batching, jit


@pytest.mark.parametrize("method", ["hkc", "lhf"])
def test_vmap_over_batch_equals_loop(method):
    clouds = [box_surface(10 + b, N, 0.01) for b in range(8)]
    nbhd = [hgjax.soft_neighbourhoods(p, method=method) for p in clouds]
    pts = jnp.asarray(np.stack(clouds))
    idx = jnp.asarray(np.stack([i for i, _ in nbhd]))
    d = jnp.asarray([dd for _, dd in nbhd])
    f = lambda p, i, d: hgjax.soft_weights(p, i, RATIO, method=method, d=d)  # noqa: E731
    batched = jax.jit(jax.vmap(f))(pts, idx, d)
    loop = np.stack([jitted_weights(method)(pts[b], idx[b], RATIO, method=method, d=d[b]) for b in range(8)])
    assert batched.shape == (8, N)
    np.testing.assert_allclose(batched, loop, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(batched.sum(axis=1), RATIO * N, rtol=1e-9)


def test_soft_resample_jit_vmap_grad():
    clouds = np.stack([box_surface(20 + b, N, 0.01) for b in range(2)])
    f = jax.jit(lambda p, tau: hgjax.soft_resample(p, RATIO, method="hkc", tau=tau), static_argnums=())
    w = jax.vmap(f, in_axes=(0, None))(clouds, 0.1)
    for b in range(2):
        idx, d = hgjax.soft_neighbourhoods(clouds[b], method="hkc")
        np.testing.assert_allclose(w[b], weights("hkc", clouds[b], idx, d), rtol=1e-9)
    c = jnp.asarray(np.random.default_rng(0).random(N))
    g = jax.jit(jax.grad(lambda p, tau, dfac: jnp.sum(c * hgjax.soft_resample(p, RATIO, tau=tau, d_factor=dfac)),
                         argnums=(0, 1, 2)))(clouds[0], 0.1, 1.3)
    assert all(np.isfinite(np.asarray(x)).all() for x in g)
    assert float(jnp.abs(g[0]).max()) > 0 and float(g[1]) != 0 and float(g[2]) != 0


def test_keeps_float32():
    pts, idx, d = setup("hkc")
    w = weights("hkc", pts.astype(np.float32), idx, np.float32(d))
    assert w.dtype == np.float32
    np.testing.assert_allclose(float(w.sum()), RATIO * N, rtol=1e-4)


# ------------------------------------------------------------------------- errors


def test_errors():
    pts, idx, d = setup("hkc")
    with pytest.raises(ValueError, match="unknown method 'nope'"):
        hgjax.soft_weights(pts, idx, RATIO, method="nope")
    with pytest.raises(ValueError, match="needs the voxel spacing d"):
        hgjax.soft_scores(pts, idx, method="hkc")
    with pytest.raises(ValueError, match="needs ratio"):
        hgjax.soft_scores(pts, idx, method="lhf")
    with pytest.raises(ValueError, match=r"points must have shape \(N, 3\)"):
        hgjax.soft_weights(pts[:, :2], idx, RATIO, d=d)
    with pytest.raises(ValueError, match="idx must have shape"):
        hgjax.soft_weights(pts, idx[:10], RATIO, d=d)
    with pytest.raises(TypeError, match="float32 or float64"):
        hgjax.soft_weights(pts.astype(np.int64), idx, RATIO, d=d)
    with pytest.raises(ValueError, match="ratio must be in"):
        hgjax.soft_weights(pts, idx, 1.5, d=d)
    with pytest.raises(ValueError, match="max_capacity=4"):
        hgjax.soft_neighbourhoods(pts, method="hkc", capacity=4)
