"""Input validation shared by every public entry point.

All checks raise ``TypeError`` for a wrong dtype and ``ValueError`` for a wrong shape or
value, and always name the argument and quote what was found. They run on the host, before
anything is traced, so they fire the same way whether or not the caller jits around them; the
value of a traced ratio, unknown until the program runs, is checked there
(:func:`check_traced_ratio`).
"""

from __future__ import annotations

import functools
import math
from typing import Any, Iterable

import jax
import jax.numpy as jnp
import numpy as np

FLOAT_DTYPES = (np.dtype(np.float32), np.dtype(np.float64))


def check_points(points: Any, name: str = "points", *, empty: bool = False) -> np.ndarray:
    """Validate a point cloud and return it as a read-only NumPy view (no copy when possible).

    Args:
      points: array-like of shape (N, 3), float32 or float64, all finite.
      name: argument name quoted in error messages.
      empty: accept N = 0 (a file's points to write).

    Returns:
      np.ndarray of shape (N, 3) with the caller's float dtype. It is a read-only view, so
      nothing downstream can modify the caller's array.

    Raises:
      TypeError: if the dtype is not float32 or float64.
      ValueError: if the shape is not (N, 3) with N >= 1 (N >= 0 with ``empty``), or a coordinate is NaN or inf.
    """
    if points is None:
        raise TypeError(f"{name} must be an array of shape (N, 3); got None")
    try:
        arr = np.asarray(points)
    except ValueError as err:  # ragged nested lists
        raise ValueError(f"{name} must be an array of shape (N, 3); got a ragged sequence ({err})") from None
    if arr.dtype not in FLOAT_DTYPES:
        raise TypeError(
            f"{name} must have dtype float32 or float64; got {arr.dtype}"
            " (convert with points.astype(np.float32) or np.float64)"
        )
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3); got {arr.shape}")
    if arr.shape[0] == 0 and not empty:
        raise ValueError(f"{name} must contain at least one point; got shape {arr.shape}")
    if arr.size and not (np.isfinite(arr.min()) and np.isfinite(arr.max())):  # NaN propagates through min and max
        bad = np.flatnonzero(~np.isfinite(arr).all(axis=1))
        raise ValueError(
            f"{name} contains {bad.size} point(s) with NaN or inf coordinates"
            f" (first at row {int(bad[0])}); drop them first, e.g. points[np.isfinite(points).all(1)]"
        )
    view = arr.view()
    view.flags.writeable = False
    return view


EXTENT_HEADROOM = 2.0**16  # squared distances, and sums of up to 2^16 of them, stay finite


def extent_range(dtype) -> tuple[float, float]:
    """(smallest, largest) non-zero extent of a cloud whose geometry ``dtype`` represents (:func:`check_extent`)."""
    info = np.finfo(dtype)
    return float(np.sqrt(info.tiny) / info.eps), float(np.sqrt(info.max / EXTENT_HEADROOM))


def check_extent(lo, hi, dtype, name: str = "points") -> float:
    """The cloud's extent, max(hi - lo) over the axes, after checking that ``dtype`` represents its geometry.

    Every method forms squared distances (the k-d tree on the host in float64, the kernels
    in the working dtype ``dtype``). They stay finite, with room for sums of 2^16 of them,
    when the extent E (the widest axis of the bounding box, i.e. of the local frame) has
    E^2 <= max / 2^16; and the squared distance of the finest spacing ``dtype`` resolves
    at that extent, (eps E)^2, is a normal number when E >= sqrt(tiny) / eps. So E is 0
    (every point equal) or within :func:`extent_range`: about [9.1e-13, 7.2e16] in float32
    and [6.7e-139, 5.2e151] in float64. Beyond it scores would be NaN, inf or silently
    those of a collapsed cloud.

    Args:
      lo, hi: (3,) float64 per-axis minimum and maximum of the cloud.
      dtype: the dtype the geometry is computed in (:func:`hgjax.working_dtype`).
      name: argument name quoted in error messages.

    Returns:
      The extent E as a Python float.

    Raises:
      ValueError: E is neither 0 nor within the range of ``dtype`` (float32 for float64
        input while JAX's x64 mode is off: the message then says so).
    """
    dtype = np.dtype(dtype)
    with np.errstate(over="ignore", invalid="ignore"):
        extent = float(np.max(np.asarray(hi, np.float64) - np.asarray(lo, np.float64)))
    smallest, largest = extent_range(dtype)
    if extent == 0 or smallest <= extent <= largest:
        return extent
    what = ("its squared distances would overflow" if not extent <= largest else
            "the squared distances it resolves would underflow to 0")
    if not np.isfinite(extent):
        extent, what = "more than float64 holds", "max - min overflows"
    else:
        extent = f"{extent:.3g}"
    hint = (' (or jax.config.update("jax_enable_x64", True): float64 input is computed in float32 while it is off)'
            if dtype == np.float32 and not jax.config.jax_enable_x64 else "")
    raise ValueError(f"{name} span {extent} along their widest axis, which {dtype} cannot represent:"
                     f" {what}; the extent must be 0 or in [{smallest:.2g}, {largest:.2g}] in {dtype}:"
                     f" rescale the points{hint}")


def check_ratio(ratio: Any, name: str = "ratio") -> float:
    """Return ``ratio`` as a float after checking 0 < ratio <= 1.

    A float32 (or float16) scalar is read as the shortest decimal that it rounds to, the
    ratio the caller wrote: ``np.float32(0.2)`` is 0.2, not 0.20000000298. Where the ratio may
    be traced, :func:`check_traced_ratio` checks it.
    """
    if isinstance(ratio, jax.core.Tracer):
        raise TypeError(f"{name} must be concrete here: it sets the number of points kept, a shape (static under"
                        " jit); got a tracer")
    if isinstance(ratio, (bool, np.bool_)) or not isinstance(ratio, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a number in (0, 1]; got {type(ratio).__name__}")
    if isinstance(ratio, np.floating) and np.finfo(ratio.dtype).bits < 64:
        ratio = float(np.format_float_positional(ratio, unique=True))
    value = float(ratio)
    if not (0.0 < value <= 1.0) or math.isnan(value):
        raise ValueError(f"{name} must be in (0, 1]; got {ratio!r}")
    return value


KEEP_ROUNDING = 1e-9  # ratio x N within this relative distance of an integer counts as that integer


def _ceil_rounded(x, xp):
    """ceil(x) with x first rounded to the nearest integer within KEEP_ROUNDING relative (``xp``: np or jnp)."""
    return xp.where(xp.abs(x - xp.round(x)) <= KEEP_ROUNDING * x, xp.round(x), xp.ceil(x))


def n_keep(n_points: int, ratio: float) -> int:
    """Number of kept points, ceil(ratio * N), with ratio * N rounded to 1e-9 relative first.

    So a ratio whose product with N is an integer up to float rounding (0.2 x 1000 =
    200.00000000000003) keeps that integer, not one more.
    """
    return int(min(max(_ceil_rounded(ratio * n_points, np), 1), n_points))


def check_keep(n_points: int, ratio: Any, count: Any) -> int:
    """The kept count of ``n_points``: ``count`` (1 <= count <= N) or ceil(ratio N) (:func:`n_keep`).

    Raises:
      TypeError: both or neither of ``ratio`` and ``count`` given, or ``count`` not an integer.
      ValueError: ``count`` or ``ratio`` out of range.
    """
    if (ratio is None) == (count is None):
        raise TypeError(f"give the ratio or the count kept, one of them; got ratio={ratio!r}, count={count!r}")
    if ratio is not None:
        return n_keep(n_points, check_ratio(ratio))
    count = check_int(count, "count", minimum=1)
    if count > n_points:
        raise ValueError(f"count must be at most the {n_points} scores; got {count}")
    return count


def n_keep_any(n_points, ratio):
    """:func:`n_keep` where ``n_points`` or ``ratio`` may be traced (jit, vmap).

    The host's count whenever ``ratio`` is concrete (:func:`n_keep_traced` for a traced
    ``n_points``); a traced ratio's product is rounded in its own dtype.
    """
    if is_concrete(ratio):
        ratio = check_traced_ratio(ratio)
        return n_keep(int(n_points), ratio) if is_concrete(n_points) else n_keep_traced(n_points, ratio)
    return jnp.clip(_ceil_rounded(ratio * n_points, jnp), 1, n_points).astype(jnp.int32)


KEEP_LIMB = 12  # bits per limb of n_keep_traced's exact product
KEEP_LIMBS = 7  # fractional limbs of the ratio: every bit of a float64 ratio >= 2^-31


def n_keep_traced(n_points, ratio: float):
    """:func:`n_keep` of a traced integer count, exactly, in int32 arithmetic (jit, vmap).

    ceil(x) with x = ratio N first rounded to 1e-9 relative equals ceil(R N) with R = ratio
    (1 - 1e-9) < 1. R N is formed exactly from R's 12-bit digits times N's two 12-bit halves
    (each product below 2^24), so the count is the host's whatever the float precision
    (float32 without x64 rounds 0.3 x 100 to 30.000002 and would keep 31).

    Args:
      n_points: traced integer scalar, 0 <= N < 2^24.
      ratio: concrete Python float in (0, 1].

    Returns:
      int32 scalar m = min(max(ceil(ratio N), 1), N), as :func:`n_keep`.
    """
    frac, digits = ratio * (1 - KEEP_ROUNDING), [0]  # digits[j]: bits 12 (j - 1) + 1 .. 12 j of R
    for _ in range(KEEP_LIMBS):
        frac *= 1 << KEEP_LIMB  # exact: a power of two
        digits.append(int(frac))
        frac -= digits[-1]
    digits.append(0)
    c = jnp.asarray(n_points, jnp.int32)
    hi, lo = c >> KEEP_LIMB, c & ((1 << KEEP_LIMB) - 1)
    # limb q (weight 2^(-12 q)) of R N = digits[q] lo + digits[q + 1] hi, carried from the last up
    carry, fraction = jnp.int32(0), jnp.bool_(False)
    for q in range(KEEP_LIMBS, 0, -1):
        limb = digits[q] * lo + digits[q + 1] * hi + carry
        fraction = fraction | ((limb & ((1 << KEEP_LIMB) - 1)) != 0)
        carry = limb >> KEEP_LIMB
    return jnp.clip(digits[1] * hi + carry + fraction.astype(jnp.int32), 1, c)


def check_min_points(n_points: int, needed: int, what: str, name: str = "points") -> None:
    """Raise when a neighbourhood of ``needed`` points cannot be formed from ``n_points``."""
    if n_points < needed:
        raise ValueError(f"{name} has {n_points} point(s), too few for {what} (needs at least {needed})")


def check_int(value: Any, name: str, *, minimum: int) -> int:
    """Return ``value`` as an int after checking its type and ``value >= minimum``."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name} must be an integer; got {type(value).__name__}")
    if value < minimum:
        raise ValueError(f"{name} must be >= {minimum}; got {value}")
    return int(value)


def check_bool(value: Any, name: str) -> bool:
    """Return ``value`` as a bool after checking it is True or False (not a string or a number)."""
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name} must be True or False; got {value!r}")
    return bool(value)


def check_positive(value: Any, name: str) -> float:
    """Return ``value`` as a float after checking it is finite and > 0."""
    return _check_real(value, name, strict=True)


def check_nonnegative(value: Any, name: str) -> float:
    """Return ``value`` as a float after checking it is finite and >= 0."""
    return _check_real(value, name, strict=False)


def _check_real(value: Any, name: str, *, strict: bool) -> float:
    """``value`` as a float after checking it is a finite real number > 0 (``strict``) or >= 0."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        kind = "a positive number" if strict else "a number >= 0"
        raise TypeError(f"{name} must be {kind}; got {type(value).__name__}")
    value = float(value)
    if not ((value > 0.0 if strict else value >= 0.0) and math.isfinite(value)):
        raise ValueError(f"{name} must be a finite number {'>' if strict else '>='} 0; got {value!r}")
    return value


VARIANTS = ("invariant", "reference")
"""Every method's ``variant``: scale-invariant (default), or the paper's (or the authors' code's) rules."""


def check_variant(variant: Any) -> str:
    """Return ``variant`` after checking it is one of :data:`VARIANTS`."""
    return check_choice(variant, "variant", VARIANTS)


def check_choice(value: Any, name: str, choices: Iterable[str]) -> str:
    """Return ``value`` after checking it is one of ``choices``."""
    choices = sorted(choices)
    if value not in choices:
        raise ValueError(f"unknown {name} {value!r}; expected one of {choices}")
    return value


def check_positive_array(value: Any, name: str, n: int) -> np.ndarray:
    """Return a scalar or (n,) array of finite values > 0 as float64 (a scalar stays 0-d)."""
    arr = np.asarray(value, dtype=np.float64) if not isinstance(value, (bool, np.bool_)) else None
    if arr is None or arr.ndim > 1 or (arr.ndim == 1 and arr.shape[0] != n):
        raise ValueError(f"{name} must be a number > 0 or an array of shape ({n},); got {value!r:.80}")
    if not (np.isfinite(arr).all() and (arr > 0).all()):
        raise ValueError(f"{name} must be finite and > 0; got {value!r:.80}")
    return arr


def is_concrete(value: Any) -> bool:
    """True unless ``value`` is a JAX tracer (checks on tracers happen where they are concrete)."""
    return not isinstance(value, jax.core.Tracer)


def check_traced_positive(value: Any, name: str):
    """``value`` unchanged after checking it is finite and > 0 when it is concrete."""
    if is_concrete(value):
        arr = np.asarray(value)
        if arr.ndim != 0 or not np.issubdtype(arr.dtype, np.number) or isinstance(value, (bool, np.bool_)):
            raise TypeError(f"{name} must be a positive number; got {value!r}")
        if not (np.isfinite(arr) and arr > 0):
            raise ValueError(f"{name} must be a finite number > 0; got {value!r}")
    return value


def check_traced_ratio(ratio: Any, name: str = "ratio"):
    """``ratio`` checked by :func:`check_ratio`: now when concrete, where the program runs when traced.

    A tracer's shape and dtype are checked now; its value where the program runs (jit, vmap,
    grad): a value out of (0, 1] calls back to the host (:func:`jax.debug.callback`), which
    stops the program with the :func:`check_ratio` message (raised as a
    :class:`jax.errors.JaxRuntimeError` by the call or where its result is first read)
    instead of giving a result. A value in range makes no callback; the program still carries
    the callback's effect, a fixed cost per call (none per point).

    Raises:
      TypeError: not a number (a tracer of bool or non-numeric dtype).
      ValueError: a concrete value out of (0, 1], or a tracer that is not a scalar.
    """
    if is_concrete(ratio):
        if hasattr(ratio, "shape") and getattr(ratio, "shape", None) == ():
            ratio = ratio.item() if not isinstance(ratio, np.floating) else ratio
        return check_ratio(ratio, name)
    if ratio.dtype == bool or not jnp.issubdtype(ratio.dtype, jnp.number):
        raise TypeError(f"{name} must be a number in (0, 1]; got a tracer of dtype {ratio.dtype}")
    if ratio.shape != ():
        raise ValueError(f"{name} must be a scalar in (0, 1]; got a tracer of shape {ratio.shape}")
    fail_where(~((ratio > 0) & (ratio <= 1)), functools.partial(_check_ratio_values, name=name), ratio)
    return ratio


def fail_where(bad, report, *operands) -> None:
    """Where the traced program runs, call ``report(*operands)`` on the host when ``bad`` holds.

    ``report`` raises (it also sees the values of a whole batch under ``vmap``: it must raise
    only for the bad ones), which stops the program: the caller's call fails with a
    :class:`jax.errors.JaxRuntimeError` carrying its message instead of giving a result, under
    ``jit``, ``vmap`` and ``grad`` alike. No callback runs otherwise (a ``lax.cond``); the
    program still carries the callback's effect, a fixed cost per call (none per point).
    """
    jax.lax.cond(jnp.any(bad), lambda *o: jax.debug.callback(report, *o), lambda *o: None, *operands)


def _check_ratio_values(values, name: str) -> None:
    """:func:`check_ratio` of the values a traced ratio takes (a batch of them under vmap), on the host."""
    values = np.asarray(values)
    values = values.astype(np.float64 if values.dtype == np.float64 else np.float32).ravel()
    bad = values[~((values > 0) & (values <= 1))]
    if bad.size:
        check_ratio(bad[0].item() if bad.dtype == np.float64 else bad[0], name)


def check_columns(nb: Any, needed: int, what: str) -> None:
    """Raise when ``nb.idx`` has fewer than ``needed`` columns."""
    if nb.idx.shape[-1] < needed:
        raise ValueError(f"nb.idx has {nb.idx.shape[-1]} columns, too few for {what} (needs {needed});"
                         " build the neighbourhoods for this method and these parameters")


def check_scale(nb: Any, method: str) -> None:
    """Raise when ``nb`` lacks the per-point voxel spacing a cube method needs."""
    if nb.scale is None:
        raise ValueError(f"method {method!r} needs nb.scale, the voxel spacing per point; build the"
                         f" neighbourhoods with hgjax.neighbourhoods(points, {method!r})")


def check_key(key, method: str, alternative: str = "") -> jax.Array:
    """Return ``key`` after checking it is a ``jax.random`` key.

    Args:
      key: a typed key (``jax.random.key``) or a legacy uint32 (2,) key (``jax.random.PRNGKey``).
      method: the method name quoted in the error.
      alternative: extra advice appended to the error for a missing key.

    Raises:
      ValueError: if ``key`` is None.
      TypeError: if ``key`` is not a key.
    """
    if key is None:
        raise ValueError(f"method {method!r} draws random numbers and needs an explicit key:"
                         f" pass key=jax.random.key(0){alternative}")
    typed = isinstance(key, jax.Array) and jax.dtypes.issubdtype(key.dtype, jax.dtypes.prng_key)
    legacy = isinstance(key, (jax.Array, np.ndarray)) and key.dtype == np.uint32 and key.shape == (2,)
    if not ((typed and key.shape == ()) or legacy):
        raise TypeError(f"key must be a jax.random key such as jax.random.key(0); got"
                        f" {type(key).__name__} {getattr(key, 'dtype', '')}{getattr(key, 'shape', '')}")
    return key


def check_kernel_size(kernel_size) -> int:
    """Return the odd kernel size k >= 3 of HKC/HKF."""
    k = check_int(kernel_size, "kernel_size", minimum=3)
    if k % 2 == 0:
        raise ValueError(f"kernel_size must be odd (3, 5, ...); got {k}")
    return k


def check_lengths(lengths) -> tuple[int, ...]:
    """Return LHF's pair of lengths (N_a, N_b), each >= 3."""
    if not isinstance(lengths, (tuple, list)) or len(lengths) != 2:
        raise ValueError(f"lengths must be a pair (N_a, N_b); got {lengths!r}")
    return tuple(check_int(n, f"lengths[{i}]", minimum=3) for i, n in enumerate(lengths))


def check_graph(points, idx, first, weights_dtype) -> None:
    """Shapes and dtypes of high_pass's arguments (static, so also valid under jit and vmap)."""
    shape, idx_shape = np.shape(points), np.shape(idx)
    first_dtype = getattr(first, "dtype", None)  # arrays and tracers only
    if first is not None and (np.shape(first) != shape[:1] or first_dtype is None
                              or not np.issubdtype(first_dtype, np.integer)):
        raise ValueError(f"first must be None or an integer array of shape ({shape[0] if shape else 'N'},);"
                         f" got {first_dtype or type(first).__name__} {np.shape(first)}")
    if len(shape) != 2 or shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3); got {shape}")
    if len(idx_shape) != 2 or idx_shape[0] != shape[0]:
        raise ValueError(f"idx must have shape ({shape[0]}, K); got {idx_shape}")
    if not np.issubdtype(points.dtype, np.floating):
        raise TypeError(f"points must be a float array; got {points.dtype}")
    if not np.issubdtype(idx.dtype, np.integer):
        raise TypeError(f"idx must be an integer array; got {idx.dtype}")
    if weights_dtype is not None and np.dtype(weights_dtype) not in FLOAT_DTYPES:
        raise TypeError(f"weights_dtype must be None, float32 or float64; got {weights_dtype!r}")


def check_scores(scores, name="scores", columns: int | None = None) -> np.ndarray:
    """Return per-point scores as an (N,) float NumPy array, or (N, ``columns``), N >= 1, without
    NaN (inf is allowed: HKC's beta is +inf where the low band vanishes)."""
    shape = "(N,)" if columns is None else f"(N, {columns})"
    if scores is None:
        raise TypeError(f"{name} must be a float array of shape {shape}; got None")
    s = np.asarray(scores)
    if not np.issubdtype(s.dtype, np.floating):
        raise TypeError(f"{name} must be a float array; got dtype {s.dtype}")
    if s.ndim != (1 if columns is None else 2) or (columns is not None and s.shape[1] != columns):
        raise ValueError(f"{name} must have shape {shape}; got {s.shape}")
    if s.size == 0:
        raise ValueError(f"{name} must hold at least one score; got shape {s.shape}")
    nan = np.isnan(s).reshape(s.shape[0], -1).any(axis=1)
    if nan.any():
        raise ValueError(f"{name} contains NaN at {int(nan.sum())} of {s.shape[0]} points")
    return s


def check_neighbourhood_list(nbs: Any, cls: type) -> list:
    """Return ``nbs`` as a list after checking it holds single-cloud ``cls`` items that stack.

    Raises:
      TypeError: ``nbs`` is not a list or tuple of ``cls``, or the points' dtypes differ.
      ValueError: ``nbs`` is empty, an item is not one cloud (points (N, 3), idx (N, K), 1 <=
        N < 2^24), or the items' methods, build parameters or the presence of ``scale`` differ.
    """
    if isinstance(nbs, cls) or not isinstance(nbs, (list, tuple)):
        raise TypeError(f"nbs must be a list of hgjax.Neighbourhoods; got {type(nbs).__name__}")
    if not nbs:
        raise ValueError("nbs must hold at least one hgjax.Neighbourhoods; got an empty list")
    for i, nb in enumerate(nbs):
        if not isinstance(nb, cls):
            raise TypeError(f"nbs[{i}] must be hgjax.Neighbourhoods; got {type(nb).__name__}")
        shape, idx_shape = np.shape(nb.points), np.shape(nb.idx)
        if len(shape) != 2 or shape[1] != 3 or len(idx_shape) != 2 or idx_shape[0] != shape[0]:
            raise ValueError(f"nbs[{i}] must be one cloud, points (N, 3) and idx (N, K); got points {shape} and"
                             f" idx {idx_shape}")
        if not 1 <= shape[0] < 1 << 24:
            raise ValueError(f"nbs[{i}] must hold 1 to 2^24 - 1 points to be stacked; got {shape[0]}")
    first = nbs[0]
    for i, nb in enumerate(nbs[1:], start=1):
        for field in ("method", "params"):
            if getattr(nb, field) != getattr(first, field):
                raise ValueError(f"nbs[{i}].{field} is {getattr(nb, field)!r} but nbs[0].{field} is"
                                 f" {getattr(first, field)!r}; a batch holds neighbourhoods built alike")
        if nb.points.dtype != first.points.dtype:
            raise TypeError(f"nbs[{i}].points has dtype {nb.points.dtype} but nbs[0].points {first.points.dtype};"
                            " build every cloud of a batch in one dtype")
        if (nb.scale is None) != (first.scale is None):
            raise ValueError(f"nbs[{i}].scale is {'None' if nb.scale is None else 'set'} but nbs[0].scale is"
                             f" {'None' if first.scale is None else 'set'}; a batch holds neighbourhoods built alike")
    return list(nbs)


def check_capacity_param(params: dict, minimum: int) -> None:
    """Check a given ``params["capacity"]`` (None or absent: nothing) as the neighbourhood builders do:
    an integer >= ``minimum``. A run that streams rows (:func:`hgjax.resample`) sizes its rows
    itself, but refuses what :func:`hgjax.neighbourhoods` refuses."""
    if params.get("capacity") is not None:
        check_int(params["capacity"], "capacity", minimum=minimum)


def check_stream(params: dict) -> dict:
    """``params`` after checking its ``chunk_size`` (an integer >= 1 or None) and ``progress`` (True or
    False), each where present: the kernel stream's parameters, checked before any work."""
    if params.get("chunk_size") is not None:
        check_int(params["chunk_size"], "chunk_size", minimum=1)
    if "progress" in params:
        check_bool(params["progress"], "progress")
    return params


def check_capacity(capacity, width: int, what: str) -> None:
    """Raise when a fixed ``capacity`` (columns) is below the fullest row's ``width``."""
    if capacity is not None and width > capacity:
        raise ValueError(f"capacity={capacity} is too small: a {what} holds {width} points;"
                         f" pass capacity >= {width} (or capacity=None to size it automatically)")


def install_hint(extra: str) -> str:
    """How to install the optional packages of ``extra``, as this project is installed (from its
    source folder; ``all`` holds every extra)."""
    return f'pip install ".[{extra}]" in the hgjax source folder (".[all]" for every optional feature)'


def check_traced_points(points: Any, name: str = "points"):
    """Validate what can be known of points that may be a tracer: shape (N, 3), N >= 1, a float dtype.

    Values are not read (they may not exist yet), so non-finite coordinates pass; concrete
    points go through :func:`check_points` instead.

    Raises:
      TypeError: not an array, or not float32 / float64.
      ValueError: not of shape (N, 3) with N >= 1.
    """
    shape, dtype = getattr(points, "shape", None), getattr(points, "dtype", None)
    if shape is None or dtype is None:
        raise TypeError(f"{name} must be an array of shape (N, 3); got {type(points).__name__}")
    if np.dtype(dtype) not in FLOAT_DTYPES:
        raise TypeError(f"{name} must have dtype float32 or float64; got {dtype}")
    if len(shape) != 2 or shape[1] != 3 or shape[0] == 0:
        raise ValueError(f"{name} must have shape (N, 3) with N >= 1; got {tuple(shape)}")
    return points
