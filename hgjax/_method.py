"""The two kinds of registry entry, scoring methods and samplers, and how a method tiles.

Each method module declares its own entry (``METHOD`` in :mod:`hgjax.scores.hkc` and its
siblings, ``SAMPLERS`` in :mod:`hgjax.samplers`) with its stages' functions and its tiling
capability; each stage's parameters are its function's keyword-only parameters
(:func:`keywords`), so the two never disagree. :data:`hgjax.METHODS` (:mod:`hgjax.engine._registry`)
collects them.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
from typing import Callable

STAGES = ("build", "score", "soft_score", "select")
PAPER = "Deng, Zhang, Ding, IEEE TIP 31, 2022"
DICTA = "Bazazian, Casas, Ruiz-Hidalgo, DICTA 2015"


@functools.cache
def keywords(fn: Callable | None) -> frozenset:
    """The keyword-only parameters of ``fn`` but ``key`` (passed apart, by :func:`hgjax.resample`); empty for None."""
    if fn is None:
        return frozenset()
    return frozenset(name for name, p in inspect.signature(fn).parameters.items()
                     if p.kind is inspect.Parameter.KEYWORD_ONLY and name != "key")


@dataclasses.dataclass(frozen=True)
class Passes:
    """A method whose tiles are scored in two passes with a global reduction between them, declared
    by the method (GFR: each tile's graph and its exact pair sums, the weights' moments over the
    whole cloud, then each tile's flows). The engine (:func:`hgjax.engine._passes.scores`) verifies
    each tile's halo, runs the passes and decides where a tile's state waits between them: in this
    process, on the Dask worker that made it, or on disk for a large cloud in this process.

    Attributes:
      reach: ``reach(build) -> float``: how far around a core location the tile must hold every
        point (the halo is verified, then doubled until it does; the first halo is just wider).
      first: ``first(index, rows, plan) -> state``: a tile's state from its host index and its core
        ``rows`` (picklable: it may travel to disk).
      summary: ``summary(state) -> part``: what the reduction takes of a tile's state.
      reduce: ``reduce(parts) -> total``: the global value of every tile's part.
      second: ``second(index, rows, state, plan, total, stream) -> (R,)``: the scores of the core
        ``rows`` in the plan's dtype (``stream``: the kernel stream's ``chunk_size`` and ``progress``).
    """

    reach: Callable
    first: Callable
    summary: Callable
    reduce: Callable
    second: Callable


@dataclasses.dataclass(frozen=True)
class Tiling:
    """How a scoring method runs in tiles, declared by the method (PDAL's ``Streamable``).

    The engine (:mod:`hgjax.engine`) and the tiled grid (:mod:`hgjax.engine`) ask a method
    only through this object, never by name.

    Attributes:
      params: ``params(n, params) -> (build, score)``: the validated build and score
        parameters of a run of ``n`` points, before any whole-cloud decision.
      reach: ``reach(build) -> (k, radii)``: the k-nearest radius a core neighbourhood spans
        and how many such radii it reaches (two for a neighbourhood sized by its neighbours'
        spacing): the first halo tried, and the neighbours per point a Dask task holds.
      resolve: ``resolve(build, stats) -> build``: the build parameters decided from the
        whole cloud, ``stats()`` giving the seeded sample's nearest distances and
        neighbourhoods (:class:`hgjax.neighbours.spatial.SampleStats`); None when nothing is decided.
      rows: ``rows(index, rows, build, dtype)``: a tile's neighbourhoods of the sorted-frame
        ``rows``, yielded batch by batch as ``(part, idx, row_args, reach)`` (a slice of
        ``rows``, their neighbour rows, per-row kernel arguments and the radius each
        neighbourhood reaches); with ``kernel``, what :func:`hgjax.engine._grid.tile_scores` streams.
      kernel: ``kernel(score_params) -> (row kernel, narrow)``: the per-neighbourhood kernel
        the tiles stream (:class:`hgjax._stream.Stream`, or :class:`hgjax._stream.NarrowStream`
        when ``narrow``).
      passes: for a method whose tiles are not independent rows, its two passes
        (:class:`Passes`); None streams ``rows`` through ``kernel`` on every tile
        (:func:`hgjax.engine._grid.tile_scores`).
      select: ``select(runner, parts, plan, key) -> (parts, keyed parts, statistics,
        largest)``: the global selection over the tiles' (gids, scores) parts, as order keys
        for :func:`hgjax.engine.select.top_pairs`; None keeps the top scores.
      whole_selection: the selection ranks every score at once (PCA-AC's Ward clustering):
        ``refused`` refuses a tile size, and a run without one scores the cloud as one tile
        before the method's ``select`` takes all the scores. False for a method whose refused
        parameters need the whole cloud to score it (GFR's reference radius).
      refused: ``refused(params) -> (qualifier, reason) | None``: why these parameters need
        the whole cloud at once (the tiled path refuses a tile size, naming the reason);
        None when the method always tiles.
    """

    params: Callable
    reach: Callable
    resolve: Callable | None = None
    rows: Callable | None = None
    kernel: Callable | None = None
    passes: Passes | None = None
    select: Callable | None = None
    whole_selection: bool = False
    refused: Callable | None = None


@dataclasses.dataclass(frozen=True)
class SampleTiles:
    """How a sampler runs in tiles, declared by the sampler: the engine (:mod:`hgjax.engine._sampled`)
    cuts the cloud, gives each tile's points to ``part``, ranks every tile's candidates at once by
    (value, global id), and fills a count beyond the candidates with the other points in index order.

    Attributes:
      plan: ``plan(points, m, **params) -> context``: the whole-cloud decisions (voxel's grid) from the
        validated (N, 3) points and the count m (None: every candidate).
      halo: ``halo(context) -> float``: the width of the halo each tile reads around its core.
      part: ``part(points, core, context) -> (values, rows)``: a tile's candidates from its points
        (n, 3) float64 (ascending global ids, halo included) and their (n,) core mask: the rows of
        its candidates and their float64 values, the largest kept first.
    """

    plan: Callable
    halo: Callable
    part: Callable


@dataclasses.dataclass(frozen=True)
class Method:
    """A registered scoring method: neighbourhoods, a per-point score, a selection.

    Attributes:
      name: registry key.
      kind: neighbourhood kind, ``"cube"``, ``"knn"`` or ``"graph"``.
      largest: True when the largest scores are kept, False for the smallest.
      needs_key: whether the default selection draws random numbers (explicit ``key``).
      summary: one line for the README and ``--help``.
      citation: where the method comes from.
      build: ``build(points, **params) -> Neighbourhoods`` (host).
      score: ``score(nb, **params) -> (N,)``, or (N, ``columns``), pure JAX; never depends on
        the ratio.
      soft_score: differentiable twin of ``score``, of the same shape.
      tiling: how it runs in tiles (:class:`Tiling`).
      bytes_per_sample: peak memory per point of a mesh sampled and resampled, rounded up (the
        command line refuses ``--samples`` beyond the memory available): ~190 bytes to sample
        fandisk.obj plus the method's own cost (measured: ~1700 for HKC; 2.9-3.7 KB in all for
        GFR). HKF, LHF and EA peaked at or below HKC at 2e5 samples; PCA-AC and the samplers
        were not measured beyond 5e4 and are given HKC's cost; MSS (32 neighbours, twice EA's)
        is given GFR's, unmeasured.
      columns: None for (N,) scores; C for (N, C) (LHF's two lengths, C = 2).
      combine: ``combine(scores, m, *, count=None) -> (N,)``: the value each point is ranked
        by, from its (N, ``columns``) scores and the kept count m (traced in
        :func:`hgjax.soft_weights`; ``count`` the real rows of a padded cloud), LHF's
        Eqs. (15)-(16); None ranks (N,) scores as they are.
      select: ``select(scores, m, *, key, **params) -> (m,) indices`` (host); None keeps the
        m top ranked values (:func:`hgjax.top_k`, ties by index).
      check_key: ``check_key(key, params) -> key``: the validated key that the selection
        with these parameters draws from (raising before any work when it is missing);
        None for a method that never draws.
      ranks_as: (another method, why) when this one keeps that one's points by definition
        (the demo says so where it sees it), or None.
      keeps_top: for a method with its own ``select``, the selection parameters with which it
        keeps the m top ranked values, ties by index (as :func:`hgjax.top_k`), so that a traced
        resample (``search="jax"``) may rank with ``jax.lax.top_k`` instead (GFR's
        ``{"mode": "top"}``); None: never.
      traced_columns: ``traced_columns(points, nb) -> int``: the columns a traced build of
        ``points`` needs where that is more than the host's widest row of ``nb`` (GFR's
        reference search reads a ball a hair wider than its rows); None: the host's rows.

    Examples:
      >>> import hgjax
      >>> entry = hgjax.METHODS["hkc"]
      >>> entry.kind, entry.largest, entry.citation
      ('cube', False, 'Deng, Zhang, Ding, IEEE TIP 31, 2022, Alg. 1, Eq. (11)')
    """

    name: str
    kind: str
    largest: bool
    needs_key: bool
    summary: str
    citation: str
    build: Callable
    score: Callable
    soft_score: Callable
    tiling: Tiling
    bytes_per_sample: int = 2048
    columns: int | None = None
    combine: Callable | None = None
    select: Callable | None = None
    check_key: Callable | None = None
    ranks_as: tuple | None = None
    keeps_top: dict | None = None
    traced_columns: Callable | None = None

    @property
    def params(self) -> dict:
        """{stage: frozenset of the keyword parameters it accepts} for each of :data:`STAGES`: the keyword-only
        parameters of ``build``, ``score``, ``soft_score`` and ``select`` (:func:`keywords`)."""
        return {"build": keywords(self.build), "score": keywords(self.score), "soft_score": keywords(self.soft_score),
                "select": keywords(self.select)}

    @property
    def accepted(self) -> frozenset:
        """Every keyword parameter of any stage."""
        return frozenset().union(*self.params.values())

    @property
    def resample_params(self) -> frozenset:
        """The parameters resampling uses: every stage's but the soft score's."""
        return self.params["build"] | self.params["score"] | self.params["select"]

    def refused(self, params: dict) -> tuple[str, str] | None:
        """Why this method with ``params`` needs the whole cloud at once, or None (:attr:`Tiling.refused`)."""
        return None if self.tiling.refused is None else self.tiling.refused(params)


@dataclasses.dataclass(frozen=True)
class Sampler:
    """A registered sampler: it picks points from the points themselves, without scores.

    Attributes:
      name: registry key.
      needs_key: whether it draws random numbers (explicit ``key``).
      summary: one line for the README and ``--help``.
      citation: where the method comes from.
      sample: ``sample(points, ratio, *, key, **params) -> (M,) indices`` (host; ``key``
        passed only when ``needs_key``).
      bytes_per_sample: as :attr:`Method.bytes_per_sample`.
      untiled: ``untiled(params) -> (qualifier, reason) | None``: why it needs the whole cloud
        at once (:attr:`Tiling.refused`); None when it always tiles.
      tiles: how it runs in tiles or on a Dask client (:class:`SampleTiles`); None samples the
        whole cloud in one process.
      ids: ``ids(n, ratio, *, key=...) -> (M,) indices``: the sample from the point count alone
        (``key`` passed only when ``needs_key``): tiles, a client and a survey of files read no
        coordinate; None reads the points.

    Examples:
      >>> import hgjax
      >>> entry = hgjax.METHODS["fps"]
      >>> isinstance(entry, hgjax.Sampler), entry.needs_key, sorted(entry.params)
      (True, False, ['backend', 'start'])
    """

    name: str
    needs_key: bool
    summary: str
    citation: str
    sample: Callable
    bytes_per_sample: int = 2048
    untiled: Callable | None = None
    tiles: SampleTiles | None = None
    ids: Callable | None = None

    @property
    def params(self) -> frozenset:
        """The keyword parameters ``sample`` accepts, ``key`` aside (:func:`keywords`)."""
        return keywords(self.sample)

    @property
    def accepted(self) -> frozenset:
        """Every keyword parameter of the sampler."""
        return self.params

    @property
    def resample_params(self) -> frozenset:
        """The parameters resampling uses (all of them)."""
        return self.params

    def refused(self, params: dict) -> tuple[str, str] | None:
        """Why this sampler needs the whole cloud at once, or None."""
        return None if self.untiled is None else self.untiled(params)

    def draw(self, points, ratio, key, **params):
        """``sample(points, ratio, **params)``, given ``key`` when the sampler draws random numbers."""
        return self.sample(points, ratio, **({"key": key} if self.needs_key else {}), **params)
