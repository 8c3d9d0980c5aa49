"""The composition of every resample, :func:`run`: plan -> tiles -> neighbourhoods -> score -> global selection.

:func:`run` is the one composition behind :func:`hgjax.resample` (one tile),
:func:`hgjax.tiles.resample` (a grid of tiles, here or on Dask workers),
:func:`hgjax.survey.resample_files` and the command line. It asks a method only through its
registry entry: a :class:`hgjax.Method`'s ``tiling`` (:class:`hgjax._method.Tiling`) or a
:class:`hgjax.Sampler`'s tiles or count (:mod:`hgjax.engine._sampled`); it holds no method's name.

1. **Plan** (:func:`hgjax.engine._plan.base`, :func:`hgjax.engine._plan.resolved`): every whole-cloud
   decision made once.
2. **Tiles**: each tile's neighbourhoods and scores on its core and a verified halo
   (:func:`hgjax.engine._grid.tile_scores`, or the method's two passes: :mod:`hgjax.engine._passes`).
3. **Selection** (:func:`hgjax.engine.select.top_pairs`): the top ceil(ratio N) by (score, global
   id) over the whole cloud, exactly, from per-tile histograms of order-preserving integer
   keys (or the method's ``tiling.select``: LHF's order statistics, GFR's keyed draw).

A method whose parameters need the whole cloud (GFR's reference radius) runs
``keep(score(neighbourhoods(points)))`` on it at once; PCA-AC (Ward clustering of every score)
scores the cloud as one tile and selects from all its scores.
"""

from __future__ import annotations

import dataclasses
import time

import jax
import numpy as np

from hgjax import _stream, _validate
from hgjax.engine import _grid, _passes, _pipeline, _plan, _registry, _runners, _sampled, select
from hgjax.neighbours import backend
from hgjax._method import Method, Sampler

__all__ = ["STAGES", "Run", "checked_tile", "first_stage", "planned", "resample", "run"]

STAGES = {"sampler": ("sample",), "whole cloud": ("neighbourhoods", "score", "keep"), "tiles": ("plan", "tiles", "keep")}
"""The stages ``on_stage`` reports, by path: a sampler; a method on the whole cloud at once; tiles."""


class Clock:
    """Reports each stage's seconds, from the end of the previous one, as ``on_stage(name, seconds)``."""

    def __init__(self, on_stage):
        self.on_stage, self.start = on_stage, time.perf_counter()

    def __call__(self, name: str, value=None):
        """``value`` unchanged, after reporting that stage ``name`` ended."""
        if self.on_stage is not None:
            now = time.perf_counter()
            self.on_stage(name, now - self.start)
            self.start = now
        return value


@dataclasses.dataclass(frozen=True)
class Run:
    """One run of the engine: the kept ids, and what decided them (for a survey's manifest).

    Attributes:
      idx: (M,) kept global ids, highest priority first.
      scores: (N,) scores, or None unless asked for (and for the samplers).
      plan: the :class:`hgjax.tiles.Plan`, or None for the samplers and a method run on the
        whole cloud at once (GFR's reference).
      selection: the global statistics of the selection: LHF's order statistics Gamma_a,
        Gamma_b (Eqs. (15)-(16)), GFR's exact score sum; empty for the others.
      threshold: the last kept (value, global id) pair, the value being the score (GFR's
        random mode: the Gumbel-perturbed log weight), or None without a plan and for a
        whole selection (PCA-AC's clusters).
    """

    idx: np.ndarray
    scores: np.ndarray | None = None
    plan: _plan.Plan | None = None
    selection: dict = dataclasses.field(default_factory=dict)
    threshold: dict | None = None


def run(points, ratio, *, method: str, tile=None, client=None, key=None, return_scores=False, on_stage=None,
        params: dict) -> Run:
    """Resample ``points`` (an array, an ``np.memmap`` or a lazy :class:`hgjax.engine._grid.Source`) with ``method``.

    Every argument is validated here, once (a method's own parameters by its ``tiling.params``).
    ``on_stage(name, seconds)``, when given, is called as each stage ends (:data:`STAGES`).

    Returns:
      :class:`Run`.

    Raises:
      TypeError, ValueError: invalid arguments, or a tile size or client for a method that
        cannot be tiled with these parameters.
    """
    clock = Clock(on_stage)
    entry = _registry.entry(method)
    return_scores = _validate.check_bool(return_scores, "return_scores")
    tile = checked_tile(entry, params, tile, client)
    _registry.check_known(entry, params)
    params = searched(entry, params)
    _validate.check_stream(params)  # the kernel stream's chunk_size and progress, before any work
    if isinstance(entry, Sampler):
        return Run(clock("sample", _sampled.sample(entry, points, ratio, tile, client, key, params)))
    if "tau" in params:  # a soft-score parameter resample does not use: still checked
        _validate.check_traced_positive(params["tau"], "tau")
    if whole_cloud(entry, params):
        idx, scores = _whole(points, ratio, entry, key, params, clock)
        return Run(idx, scores if return_scores else None)
    params = dict(params)
    stream = {k: params.pop(k) for k in ("chunk_size", "progress") if k in params}
    if entry.check_key is not None:
        key = entry.check_key(key, params)
    plan, runner = clock("plan", planned(points, ratio, entry, tile, params, client))
    if entry.tiling.passes is None:
        parts = runner.tiles(_grid.tile_scores, plan, stream)
    else:
        parts = _passes.scores(runner, plan, stream)
    clock("tiles")
    if entry.tiling.whole_selection:
        scores = _plan.gathered(runner, parts, plan)
        idx = _pipeline.kept(entry, scores, plan.m, key, _registry.split(entry, "select", params))
        return Run(clock("keep", idx), scores if return_scores else None, plan)
    if entry.tiling.select is None:
        keyed, selection, largest = runner.each(select.part_keys, parts, entry.largest), {}, entry.largest
    else:
        parts, keyed, selection, largest = entry.tiling.select(runner, parts, plan, key)
    idx, (last_key, last_gid) = select.top_pairs(keyed, plan.m, run=runner.run(keyed), boundary=True)
    clock("keep")
    threshold = {"value": select.key_value(last_key, largest=largest), "gid": last_gid}
    return Run(idx, _plan.gathered(runner, parts, plan) if return_scores else None, plan, selection, threshold)


def searched(entry: Method | Sampler, params: dict) -> dict:
    """``params`` with the run's neighbour search: the one named (validated), else the backend's default
    (:func:`hgjax.neighbours.backend.default_search`); every method's tiles build with either.

    Raises:
      ValueError: an unknown ``search``.
    """
    if isinstance(entry, Sampler):
        return params
    if "search" in params:
        _validate.check_choice(params["search"], "search", backend.SEARCHES)
        return params
    return {**params, "search": backend.default_search()}


def whole_cloud(entry: Method, params: dict) -> bool:
    """Whether a run of ``entry`` with ``params`` builds the whole cloud's neighbourhoods at once: a method
    that cannot run in tiles with these parameters and does not select on the whole cloud anyway."""
    return entry.refused(params) is not None and not entry.tiling.whole_selection


def first_stage(entry: Method | Sampler, params: dict) -> str:
    """The first stage (:data:`STAGES`) of a one-tile run of ``entry`` with ``params``: a sampler's, the
    whole cloud's, or the plan of its tiles."""
    if isinstance(entry, Sampler):
        return STAGES["sampler"][0]
    return STAGES["whole cloud" if whole_cloud(entry, params) else "tiles"][0]


def checked_tile(entry: Method | Sampler, params: dict, tile, client) -> float | None:
    """The validated ``tile``, once ``entry`` with ``params`` is known to run in tiles where a tile or client is given.

    Raises:
      ValueError: a ``tile`` or ``client`` for a method that needs the whole cloud; an invalid ``tile``.
    """
    refused = entry.refused(params)
    if refused is not None and (tile is not None or client is not None):
        raise ValueError(f"method {entry.name!r}{refused[0]} cannot run in tiles (tile={tile!r}): {refused[1]};"
                         " pass tile=None")
    return None if tile is None else _validate.check_positive(tile, "tile")


def planned(points, ratio, entry: Method, tile, params: dict, client) -> tuple[_plan.Plan, _runners.Here]:
    """(the resolved plan, the runner of its tiled cloud) of a scoring method's run (``tile`` validated)."""
    pts = points if isinstance(points, _grid.Source) else _validate.check_points(points)
    n = pts.n if isinstance(pts, _grid.Source) else pts.shape[0]
    plan, cloud = _plan.base(pts, _validate.n_keep(n, _validate.check_ratio(ratio)), entry, tile, params, client)
    runner = _runners.runner(cloud, client, entry.tiling.reach(plan.build)[0])
    return _plan.resolved(plan, runner), runner


def _whole(points, ratio, entry: Method, key, params: dict, clock: Clock) -> tuple[np.ndarray, np.ndarray]:
    """(kept indices, scores) of a scoring method on the whole cloud at once (GFR's reference)."""
    pts = _validate.check_points(points)
    ratio = _validate.check_ratio(ratio)
    nb = clock("neighbourhoods", _pipeline.neighbourhoods(pts, entry.name, **params))
    scores = clock("score", np.asarray(_pipeline.score(nb, entry.name, **params)))
    return clock("keep", _pipeline.keep(scores, ratio, method=entry.name, key=key, **params)), scores


def resample(points, ratio: float, *, method: str = _registry.DEFAULT, key=None, return_scores: bool = False, on_stage=None,
             traced: bool | None = None, **params):
    """Indices of the ceil(ratio * N) points that a method keeps.

    The one-tile case of :func:`hgjax.tiles.resample` (same signature, without ``tile`` and
    ``client``): for a scoring method, ``keep(score(neighbourhoods(points, method)), ratio)``
    streamed through one compiled kernel; samplers work on the points directly.

    Args:
      points: (N, 3) float32 or float64 (NumPy, JAX or ``np.memmap``); never modified.
      ratio: fraction alpha of points to keep, in (0, 1]. ceil(ratio N) points are kept,
        with ratio N first rounded to 1e-9 relative (and a float32 ratio read as the
        decimal it prints as), so ``np.float32(0.2)`` of 1000 points keeps 200.
      method: a key of :data:`hgjax.METHODS` (default ``"hkc"``).
      key: ``jax.random`` key for methods that draw random numbers (ignored by the others).
      return_scores: also return every point's score.
      on_stage: ``on_stage(name, seconds)``, called as each stage ends: ``"sample"`` for a
        sampler; ``"plan"`` (bounds, resolved parameters), ``"tiles"`` (neighbourhoods and
        scores) and ``"keep"`` for a scoring method; ``"neighbourhoods"``, ``"score"`` and
        ``"keep"`` for one run on the whole cloud at once (GFR's reference)
        (:data:`hgjax.engine.STAGES`).
      traced: run the whole resample as one pure-JAX program, its neighbour search included
        (``search="jax"``), which a caller's ``jax.jit``, ``jax.vmap`` or ``jax.grad`` traces
        (``ratio`` and shape parameters static); it returns a JAX int32 array, equal to the
        host's. Every scoring method whose selection keeps its top scores runs so (GFR with
        ``mode="top"``). Default: when ``points`` are a JAX tracer. Otherwise the resample runs
        on the host's engine with either neighbour search and returns NumPy.
      **params: keyword parameters of the method's stages (e.g. ``variant``, ``lengths``,
        ``chunk_size``, ``progress``), and ``search``: the neighbour search, ``"host"`` (a k-d
        tree) or ``"jax"`` (the traced search; the GPU/TPU default), the same neighbourhoods either way.

    Returns:
      (M,) int64 unique indices into ``points``, M = ceil(ratio N), from the highest to the
      lowest keep priority (ties broken by index), so ``points[idx]`` is the resampled cloud;
      with ``return_scores``, (indices, scores) with scores (N,) in the working dtype: the
      values ranked (LHF: its two lengths combined at the kept count, Eqs. (15)-(16)), or
      None for the samplers.

    Raises:
      TypeError, ValueError: invalid points, ratio, method or parameters.

    Examples:
      >>> import numpy as np, hgjax
      >>> pts = hgjax.eval.box_union_cloud(seed=0, n_points=2000).points
      >>> idx = hgjax.resample(pts, 0.2, method="hkc")
      >>> idx.shape, len(set(idx.tolist()))
      ((400,), 400)
    """
    if _stream.is_traced(points) if traced is None else _validate.check_bool(traced, "traced"):
        if params.setdefault("search", "jax") != "jax":
            raise ValueError("traced=True runs the whole resample in JAX, its neighbour search too: pass search='jax'"
                             f" or no search; got search={params['search']!r}")
        return _pure(points, ratio, _registry.scoring(method), return_scores, params)
    if _stream.is_traced(points):
        raise TypeError("points are traced (inside jax.jit, vmap or grad): resample them with traced=True (the"
                        " default for traced points)")
    done = run(points, ratio, method=method, key=key, return_scores=return_scores, on_stage=on_stage, params=params)
    return (done.idx, done.scores) if return_scores else done.idx


def keeps_top(entry: Method, params: dict) -> bool:
    """Whether ``entry``'s selection with ``params`` keeps the top scores, ties by index (:attr:`Method.keeps_top`)."""
    return entry.keeps_top is not None and all(params.get(k) == v for k, v in entry.keeps_top.items())


def _pure(points, ratio, entry: Method, return_scores, params: dict):
    """``top_k(score(neighbourhoods(points, search="jax")))``: a resample in pure JAX, under a caller's ``jit``.

    The kept count ceil(ratio N) sets a shape: ``ratio`` is static. Ties are broken by index
    as :func:`hgjax.top_k` breaks them (``jax.lax.top_k`` lists the lower index first).
    """
    if entry.select is not None and not keeps_top(entry, params):
        how = ("" if entry.keeps_top is None else
               "; pass " + ", ".join(f"{k}={v!r}" for k, v in entry.keeps_top.items()) + " to keep its top scores")
        raise ValueError(f"method {entry.name!r} selects on the host with these parameters, which a traced resample"
                         f" (traced=True, or points traced by jax.jit) cannot run inside one program{how}")
    return_scores = _validate.check_bool(return_scores, "return_scores")
    nb = _pipeline.neighbourhoods(points, entry.name, **params)
    scores = _pipeline.score(nb, entry.name, **params)
    m = _validate.n_keep(nb.points.shape[0], _validate.check_ratio(ratio))
    ranked = scores if entry.combine is None else entry.combine(scores, m)
    idx = jax.lax.top_k(ranked if entry.largest else -ranked, m)[1]
    return (idx, ranked) if return_scores else idx
