"""A survey of files resampled as one cloud: one output per input, and a manifest of the run.

:func:`resample_files` reads the inputs lazily (LAS/LAZ headers, then one task per file for
its exact bounds, then each tile reads its core and halo from the files its box meets, of a
COPC file only the octree nodes that meet it: :func:`hgjax.io.chunks`) and runs the engine
(:func:`hgjax.engine.run`) on them as one cloud, so the kept points are exactly those of
:func:`hgjax.tiles.resample` on the concatenated cloud.
"""

from __future__ import annotations

import dataclasses
import glob
import json
import os
import tempfile

import numpy as np

from hgjax import _registry, _tiling, _validate, engine, io, spatial
from hgjax._method import Method

__all__ = ["MANIFEST", "SurveyResult", "resample_files"]

MANIFEST = "hgjax-manifest.json"


@dataclasses.dataclass(frozen=True)
class _Source:
    """One file of a survey: its path, the global id of its first point, its point count, its exact bounds."""

    path: str
    start: int
    count: int
    lo: np.ndarray  # (3,) float64 per-axis minimum of its coordinates
    hi: np.ndarray  # (3,) float64 per-axis maximum


@dataclasses.dataclass(frozen=True)
class _Sources(_tiling.Source):
    """A survey's files as one cloud, described by their :class:`_Source` records (no coordinates).

    ``progress``: report each finished tile task on stderr.
    """

    files: tuple
    progress: bool = False

    @property
    def n(self) -> int:
        return sum(f.count for f in self.files)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-axis float64 min and max of the whole survey (the exact reduction of the files' bounds)."""
        return np.min([f.lo for f in self.files], axis=0), np.max([f.hi for f in self.files], axis=0)

    def cloud(self, origin: np.ndarray, lo: np.ndarray, hi: np.ndarray, tile, client) -> "_Survey":
        """The survey tiled by the grid of ``tile`` (its census runs on ``client``)."""
        return _Survey(self, origin, lo, hi, tile, client)


class _Survey(_tiling.Cloud):
    """A survey of files tiled as one cloud, read lazily: a tile reads its core and halo from the files its box meets.

    The grid and ownership are :class:`_tiling.Cloud`'s. The client holds the files' records, each
    occupied tile's point count and the owners of the sampled ids (:func:`hgjax.spatial.sample_ids`),
    taken by one census task per file; never the coordinates. :meth:`gather` reads, one chunk
    at a time, only the files whose exact bounds meet the tile's box, and of a COPC file only
    the octree nodes whose bounds meet it.
    """

    def __init__(self, sources: _Sources, origin: np.ndarray, lo: np.ndarray, hi: np.ndarray, tile: float | None,
                 client=None):
        self.origin, self.lo, self.hi, self.tile, self.files = origin, lo, hi, tile, sources.files
        self.source, self.keep, self._indices, self.n = None, False, {}, sources.n
        self.progress = sources.progress
        self.shape = (1, 1, 1) if tile is None else _tiling.grid_shape(lo, hi, tile)
        wanted = spatial.sample_ids(self.n)
        counts, self._owners = {}, {}
        for codes, sizes, gids, owner in _tiling.map_tasks(client, _census, range(len(self.files)), self, wanted):
            for c, r in zip(codes.tolist(), sizes.tolist()):
                counts[c] = counts.get(c, 0) + r
            self._owners.update(zip(gids.tolist(), owner.tolist()))
        self.counts = {tuple(int(i) for i in np.unravel_index(c, self.shape)): counts[c] for c in sorted(counts)}

    def occupied(self) -> list:
        return list(self.counts)

    def core_size(self, cell) -> int:
        return self.counts[cell]

    def owners(self, wanted: np.ndarray) -> list:
        mine = {tuple(int(i) for i in np.unravel_index(self._owners[g], self.shape)) for g in wanted.tolist()}
        return [cell for cell in self.counts if cell in mine]

    def codes(self, x: np.ndarray) -> np.ndarray:
        """(R,) int64 raveled grid cell owning each point of frame coordinates ``x``."""
        if self.tile is None:
            return np.zeros(x.shape[0], np.int64)
        return np.ravel_multi_index(self.cells(x).T, self.shape)

    def gather(self, cell, halo: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        box_lo, box_hi = self.box(cell, halo)
        slack = 1e-9 * (self.hi - self.lo + 1.0)  # a core point may sit an ulp outside its cell's box
        code = np.ravel_multi_index(cell, self.shape)
        gids, xs, cores = [], [], []
        for f in self.files:
            if ((f.hi - self.origin < box_lo - slack) | (f.lo - self.origin > box_hi + slack)).any():
                continue
            for first, xyz in io.chunks(f.path, box=(box_lo + self.origin - slack, box_hi + self.origin + slack)):
                x = xyz - self.origin
                core = self.codes(x) == code
                keep = np.flatnonzero(core | ((x >= box_lo) & (x < box_hi)).all(axis=1))
                gids.append(f.start + first + keep)
                xs.append(x[keep])
                cores.append(core[keep])
        return np.concatenate(gids), np.concatenate(xs), np.concatenate(cores)


def _census(i: int, survey: _Survey, wanted: np.ndarray) -> tuple:
    """(occupied cell codes, their point counts, the sampled global ids in file ``i``, their cell codes)."""
    f = survey.files[i]
    cells, sizes, mine, owner = [], [], wanted[(wanted >= f.start) & (wanted < f.start + f.count)], []
    for first, xyz in io.chunks(f.path):
        c = survey.codes(xyz - survey.origin)
        u, r = np.unique(c, return_counts=True)
        cells.append(u)
        sizes.append(r)
        owner.append(c[mine[(mine >= f.start + first) & (mine < f.start + first + c.size)] - f.start - first])
    cells, at = np.unique(np.concatenate(cells), return_inverse=True)
    return cells, np.bincount(at, weights=np.concatenate(sizes)).astype(np.int64), mine, np.concatenate(owner)


@dataclasses.dataclass(frozen=True)
class SurveyResult:
    """What :func:`resample_files` did.

    Attributes:
      written: output paths written, in input order.
      skipped: output paths left as they were (``skip_existing``).
      failures: {input path: error message} of the inputs that could not be read or written.
      manifest: path of the manifest JSON, or None when nothing was resampled.
    """

    written: list
    skipped: list
    failures: dict
    manifest: str | None


def _survey_paths(paths) -> list[str]:
    """Files of ``paths`` (files or glob patterns), in the order given, each once."""
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    found = []
    for p in paths:
        p = os.fspath(p)
        matches = sorted(glob.glob(p)) if glob.has_magic(p) else [p]
        if not matches:
            raise ValueError(f"paths: the pattern {p!r} matches no file")
        found += [m for m in matches if m not in found]
    if not found:
        raise ValueError("paths must name at least one file; got none")
    return found


def _scan(entry: tuple):
    """(count, lo (3,), hi (3,)) of a file from a read of all its coordinates, or the message of why it cannot be read.

    ``entry`` is (path, the point count its header announces or None); a LAS/LAZ file must hold
    the points its header announces, all finite.
    """
    path, announced = entry
    n, lo, hi = 0, np.full(3, np.inf), np.full(3, -np.inf)
    try:
        for _, xyz in io.chunks(path):
            if not np.isfinite(xyz).all():
                raise io.PointCloudReadError(f"cannot read {path}: non-finite coordinates (corrupt scale or offset)")
            n += xyz.shape[0]
            lo, hi = np.minimum(lo, xyz.min(axis=0, initial=np.inf)), np.maximum(hi, xyz.max(axis=0, initial=-np.inf))
        if announced is not None and n != announced:
            raise io.PointCloudReadError(f"cannot read {path}: the file holds {n} points; its header announces"
                                         f" {announced} (truncated or corrupt)")
        if n == 0:
            raise io.PointCloudReadError(f"cannot read {path}: the file holds no points")
    except io.PointCloudReadError as err:
        return str(err)
    return n, lo, hi


def _stage(disk: np.memmap, start: int, path: str) -> None:
    """Copy the float64 coordinates of ``path`` into ``disk[start:]``, one chunk at a time."""
    for first, xyz in io.chunks(path):
        disk[start + first:start + first + xyz.shape[0]] = xyz


def _run_record(paths, method, ratio, tile, key, params) -> dict:
    """The part of the manifest that decides whether an earlier run's outputs can be kept."""
    inputs = [{"path": os.path.abspath(p), "bytes": os.path.getsize(p) if os.path.exists(p) else None,
               "mtime_ns": os.stat(p).st_mtime_ns if os.path.exists(p) else None} for p in paths]
    return json.loads(json.dumps({"method": method, "ratio": ratio, "tile": tile, "key": key, "params": params,
                                  "inputs": inputs}, default=_tiling.jsonable))


def resample_files(paths, out_dir, ratio: float, *, method: str = _registry.DEFAULT, tile: float | None = None, client=None,
                   key=None, keep_going: bool = False, skip_existing: bool = False, progress: bool = False,
                   **params) -> SurveyResult:
    """Resample a survey of files as one cloud, writing the kept points of each file beside the others.

    Global ids run in file order, then point order within each file, and the kept ids are
    exactly those of :func:`resample` on the concatenated cloud. The survey is read lazily:
    the LAS/LAZ headers first (point counts), then one task per file reads its coordinates
    (LAS/LAZ in chunks of :data:`hgjax.io.CHUNK_ROWS` points, through laspy) for its exact bounds and checks
    them, so every input is checked before any output is written; one census task per file
    counts the points of each tile; each tile's task reads its core and halo from only the
    files whose bounds meet its box, and of a COPC file (known by its COPC info VLR) only the
    octree nodes whose bounds meet it (a node's points are numbered from the point counts of
    the nodes stored before it in the file, so ids are those of the whole file read in order).
    The client holds per file its path, count and bounds,
    per tile its count, and, while writing, one input file with its attributes; never the
    survey's coordinates. Tasks read the inputs by absolute path, so Dask workers must see
    them. ``uniform`` reads no coordinate after that check (a point's draw comes from the key
    and its global id). The methods that need the whole cloud at once read it from a float64
    memmap (24 bytes a point, on disk) in a hidden temporary directory of ``out_dir`` instead,
    and hold what they need per point in memory: ``voxel`` (its count-targeted edge search
    assigns every point of the cloud to a voxel, pass after pass, until the kept count is
    reached), GFR's ``variant="reference"`` (its squared radius comes from the min and max nearest
    distance of the whole cloud) and those :func:`resample` runs untiled (``fps``, ``pca_ac``).

    Args:
      paths: files or glob patterns (each pattern's matches sorted), any format
        :func:`hgjax.io.read_points` reads; never modified.
      out_dir: directory of the outputs (created if missing): one file per input, same name.
      ratio: fraction of the whole survey kept, in (0, 1].
      method, tile, client, key, **params: as :func:`resample`.
      keep_going: an unreadable input is reported in the result and left out of the survey
        instead of raising; an output that cannot be written is reported likewise.
      skip_existing: keep outputs that exist when the manifest in ``out_dir`` records the
        same method, ratio, tile, key, parameters and inputs (paths, sizes, modification
        times); only missing outputs are written.
      progress: write one line on stderr as each tile task of each pass finishes
        (``hgjax tiles: tile scores 3/12 tile (0, 1, 0)``).

    Returns:
      :class:`SurveyResult`. Each output holds its input's kept points in input order, with
      every attribute, and a LAS/LAZ output keeps its input's header (point format, scale,
      offset, extra dimensions); the output of a COPC input is a plain LAZ file of the same
      name (its octree VLRs are dropped: nothing here writes COPC). ``out_dir/hgjax-manifest.json`` records the run, the
      number of points N and kept M, each output's count, and under ``resolved`` what
      decided the kept set: the :class:`Plan` (origin, bounds, resolved build and score
      parameters, halo), the selection's global statistics (LHF's Gamma_a and Gamma_b,
      GFR's score sum) and the threshold (the last kept score and its global id), so a
      rerun can be checked against it; outputs and manifest are written atomically.

    Raises:
      ValueError: ``paths`` matches no file, or an output would be one of the inputs.
      hgjax.io.PointCloudReadError: an input cannot be read (without ``keep_going``), before
        any output is written.
      TypeError, ValueError: as :func:`resample`.
    """
    from hgjax import __version__

    keep_going = _validate.check_bool(keep_going, "keep_going")
    skip_existing = _validate.check_bool(skip_existing, "skip_existing")
    progress = _validate.check_bool(progress, "progress")
    files = _survey_paths(paths)
    out_dir = os.fspath(out_dir)
    targets = {p: os.path.join(out_dir, os.path.basename(p)) for p in files}
    if len(set(targets.values())) < len(files):
        raise ValueError("paths: two inputs have the same file name, so their outputs in out_dir would collide")
    clash = [p for p in files if os.path.abspath(targets[p]) == os.path.abspath(p)]
    if clash:
        raise ValueError(f"out_dir: the output of {clash[0]} would overwrite it; choose another directory")
    record = _run_record(files, method, ratio, tile, key, params)
    manifest = os.path.join(out_dir, MANIFEST)
    done = set()
    if skip_existing and os.path.isfile(manifest):
        with open(manifest) as fh:
            old = json.load(fh)
        if old.get("run") == record:
            done = {p for p in files if os.path.exists(targets[p])}
    if done and len(done) == len(files):
        return SurveyResult([], [targets[p] for p in files], {}, manifest)
    failures, announced = {}, {}
    for p in files:  # headers first: a LAS/LAZ file whose header cannot be read fails before any coordinate is
        try:
            announced[p] = io.header_count(p)
        except io.PointCloudReadError as err:
            if not keep_going:
                raise
            failures[p] = str(err)
    sources, counts = [], {}
    for p, got in zip(announced, _tiling.map_tasks(client, _scan, [(os.path.abspath(p), c) for p, c in announced.items()])):
        if isinstance(got, str):
            if not keep_going:
                raise io.PointCloudReadError(got)
            failures[p] = got
            continue
        counts[p] = got[0]
        sources.append(_Source(os.path.abspath(p), sum(counts.values()) - got[0], *got))
    if not sources:
        raise io.PointCloudReadError(f"no input could be read: {failures}")
    survey, n = _Sources(tuple(sources), progress), sum(counts.values())
    starts = {p: f.start for p, f in zip(counts, sources)}
    os.makedirs(out_dir, exist_ok=True)
    entry = _registry.entry(method)
    lazily = entry.refused(params) is None if isinstance(entry, Method) else entry.lazy
    if lazily:
        run = engine.run(survey, ratio, method=method, tile=tile, client=client, key=key, params=dict(params))
    else:  # the methods that need the whole cloud at once read it from a float64 memmap
        with tempfile.TemporaryDirectory(dir=out_dir, prefix=".hgjax-survey-") as work:
            disk = np.memmap(os.path.join(work, "xyz.f8"), dtype=np.float64, mode="w+", shape=(n, 3))
            for f in sources:
                _stage(disk, f.start, f.path)
            disk.flush()
            run = engine.run(disk, ratio, method=method, tile=tile, client=client, key=key, params=dict(params))
            del disk
    kept = np.sort(run.idx)
    written, skipped, outputs = [], [], {}
    for p, start in starts.items():
        local = kept[np.searchsorted(kept, start):np.searchsorted(kept, start + counts[p])] - start
        outputs[p] = {"output": os.path.abspath(targets[p]), "points": counts[p], "kept": int(local.size)}
        if p in done:
            skipped.append(targets[p])
            continue
        try:
            data = io.read_points(p)
            if len(data) != counts[p]:
                raise io.PointCloudReadError(f"cannot read {p}: it changed while being resampled")
            kept_data = data.subset(local)
            io.write_points(targets[p], kept_data.points, attributes=kept_data.attributes, header=kept_data.header)
        except (io.PointCloudReadError, io.PointCloudWriteError, OSError, ValueError) as err:
            if not keep_going:
                raise
            failures[p] = str(err)
            continue
        written.append(targets[p])
    resolved = {"plan": None if run.plan is None else run.plan.record(), "selection": run.selection,
                "threshold": run.threshold}
    body = {"hgjax": __version__, "run": record, "resolved": resolved, "n": n, "m": int(kept.size),
            "outputs": list(outputs.values()), "failures": failures}
    text = json.dumps(body, indent=2, default=_tiling.jsonable).encode()
    io._atomic_write(os.path.abspath(manifest), lambda fh: fh.write(text))
    return SurveyResult(written, skipped, failures, manifest)
