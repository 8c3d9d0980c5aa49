"""A survey of files resampled as one cloud: one output per input, and a manifest of the run.

:func:`resample_files` reads the inputs lazily (LAS/LAZ headers, then one task per file for
its exact bounds, then each tile reads its core and halo from the files its box meets, of a
COPC file only the octree nodes that meet it: :func:`hgjax.io.chunks`) and runs the engine
(:func:`hgjax.engine.run`) on them as one cloud, so the kept points are exactly those of
:func:`hgjax.tiles.resample` on the concatenated cloud.

The manifest (:data:`MANIFEST`, one per output directory) is the one resume rule of every
mode, a survey's and the command line's file by file: :func:`run_record` says what decides an
output, :func:`reusable` whether an output can be kept and why not, :func:`write_manifest`
records the outputs written, :func:`read_manifest` refuses a file that is not a manifest.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import glob
import json
import os
import re
import secrets
import socket
import time

import numpy as np

from hgjax import _progress, _validate, io
from hgjax.engine import _grid, _plan, _registry, _run, _runners
from hgjax.neighbours import spatial
from hgjax._method import Method

__all__ = ["MANIFEST", "ManifestError", "SurveyResult", "read_manifest", "resample_files", "reusable", "run_record",
           "write_manifest"]

MANIFEST = "hgjax-manifest.json"
"""The file name of the manifest in a directory of outputs."""

_LABELS = {"hgjax": "the hgjax version", "command": "the command", "method": "the method", "ratio": "the ratio",
           "count": "the count", "voxel_size": "the voxel size", "params": "the parameters", "key": "the key",
           "tile": "the tile", "dtype": "the dtype", "order": "the order", "samples": "the samples",
           "seed": "the seed"}
"""How :func:`reusable` names a field of a run record that changed."""
_STREAM = ("chunk_size", "progress")
"""Parameters of the kernel stream, which never change a result (not recorded)."""


class ManifestError(ValueError):
    """Raised when a manifest file is not one hgjax wrote (invalid JSON, or not a manifest's shape)."""


def run_record(inputs, *, method: str, ratio, key=None, params=None, **options) -> dict:
    """What decides an output, as a manifest records it (JSON data).

    Args:
      inputs: the input files the output is made from (a survey's output: every input of the
        survey, since all of them decide its kept points).
      method: the method's name.
      ratio: the fraction kept (None where ``options`` say how many instead: ``count``).
      key: the ``jax.random.key``, recorded by its data, for a method that draws random numbers
        (its registry entry's ``needs_key``); None otherwise, so another key keeps the outputs of a
        deterministic method.
      params: the method's parameters (the kernel stream's ``chunk_size`` and ``progress`` left out:
        they never change a result; so is a parameter given its default value
        (:func:`hgjax.engine._registry.defaults`), so ``k=16`` records the run of the default ``k``).
      **options: anything else that changes the output (a survey's ``tile`` and working
        ``dtype``; the command line's command, count, voxel size, order, samples and seed).

    Returns:
      {"hgjax": version, "method", "ratio", "key", "params", **options, "inputs": [{"path" (absolute),
      "bytes", "mtime_ns"} per input, None where missing]}.

    Examples:
      >>> record = run_record([], method="hkc", ratio=0.2, params={"k": 10})
      >>> record["method"], record["ratio"], record["key"], record["params"], record["inputs"]
      ('hkc', 0.2, None, {'k': 10}, [])
    """
    from hgjax import __version__

    inputs = [os.fspath(p) for p in inputs]
    stats = [os.stat(p) if os.path.exists(p) else None for p in inputs]
    given = {k: v for k, v in (params or {}).items() if k not in _STREAM}
    defaults = _registry.defaults(_registry.entry(method))
    params = {k: v for k, v in given.items() if k not in defaults or _json(v) != _json(defaults[k])}
    record = {"hgjax": __version__, "method": method, "ratio": ratio,
              "key": key if _registry.entry(method).needs_key else None, "params": params, **options,
              "inputs": [{"path": os.path.abspath(p), "bytes": None if st is None else st.st_size,
                          "mtime_ns": None if st is None else st.st_mtime_ns} for p, st in zip(inputs, stats)]}
    return json.loads(json.dumps(record, default=_plan.jsonable))


def _json(value) -> str:
    return json.dumps(value, default=_plan.jsonable, sort_keys=True)


def read_manifest(path) -> dict:
    """The manifest at ``path``, checked to be one; {} where there is none.

    Args:
      path: the manifest file (:data:`MANIFEST` in a directory of outputs).

    Returns:
      The manifest: {"hgjax", "outputs": [{"output" (absolute path), "bytes", "mtime_ns", "run"
      (the output's :func:`run_record`, else the manifest's own "run"), ...}], ...}.

    Raises:
      ManifestError: the file is not valid JSON, is nested too deeply to read, or is not the shape
        of a manifest (named, with how to go on).

    Examples:
      >>> read_manifest("no-such-folder/hgjax-manifest.json")
      {}
    """
    path = os.fspath(path)
    if not os.path.exists(path):
        return {}
    advice = "remove it to recompute every output, or write to another directory"
    try:
        with open(path, "rb") as fh:
            data = json.loads(fh.read().decode("utf-8"))
    except ValueError as err:  # JSONDecodeError and UnicodeDecodeError
        raise ManifestError(f"{path} is not an hgjax manifest: invalid JSON ({err}); {advice}") from None
    except RecursionError:
        raise ManifestError(f"{path} is not an hgjax manifest: its JSON is nested too deeply to read; {advice}") from None
    problem = _misshapen(data)
    if problem:
        raise ManifestError(f"{path} is not an hgjax manifest: {problem}; {advice}")
    return data


def _misshapen(data) -> str | None:
    """What keeps ``data`` from being a manifest's shape, or None."""
    if not isinstance(data, dict):
        return f"a JSON {type(data).__name__}, not an object"
    if not isinstance(data.get("outputs"), list):
        return 'no "outputs" list'
    if "run" in data and not isinstance(data["run"], dict):
        return 'its "run" is not an object'
    for entry in data["outputs"]:
        if not (isinstance(entry, dict) and isinstance(entry.get("output"), str)):
            return 'an entry of "outputs" is not an object with an "output" path'
        run = entry.get("run", data.get("run"))
        if not (isinstance(run, dict) and isinstance(run.get("inputs"), list)):
            return f'the entry of {entry["output"]} has no "run" object with "inputs"'
    return None


def reusable(manifest: dict, output, record: dict) -> tuple[bool, str]:
    """Whether ``output`` can be kept as it is, and the line that says so or why it is recomputed.

    It is kept only when it exists as ``manifest`` recorded it (same size and modification
    time) and its recorded run equals ``record``: method, ratio or count, parameters, key,
    hgjax version, every option and each input's path, size and modification time.

    Args:
      manifest: a manifest (:func:`read_manifest`; {} where there is none).
      output: the output path, as the line names it.
      record: the run that would write it now (:func:`run_record`).

    Returns:
      (True, "skipped OUTPUT: ... (--skip-existing)") or (False, "recomputing OUTPUT: why").

    Examples:
      >>> reusable({}, "no-such-file.ply", run_record([], method="hkc", ratio=0.2))
      (False, 'recomputing no-such-file.ply: it does not exist')
    """
    output = os.fspath(output)
    if not os.path.exists(output):
        return False, f"recomputing {output}: it does not exist"
    entry = {e["output"]: e for e in manifest.get("outputs", [])}.get(os.path.abspath(output))
    if entry is None:
        return False, f"recomputing {output}: {MANIFEST} does not record it"
    st = os.stat(output)
    if (entry.get("bytes"), entry.get("mtime_ns")) != (st.st_size, st.st_mtime_ns):
        return False, f"recomputing {output}: it changed since {MANIFEST} recorded it"
    changes = _changes(entry.get("run", manifest.get("run")), record)
    if changes:
        return False, f"recomputing {output}: {'; '.join(changes)}"
    return True, (f"skipped {output}: {MANIFEST} records the same method, ratio, parameters, key, version and"
                  " inputs (--skip-existing)")


def _changes(old: dict, new: dict) -> list[str]:
    """What differs between two run records, one phrase per field, in the order of ``new``."""
    said = []
    for name in [*new, *(n for n in old if n not in new)]:
        if name == "inputs" or old.get(name) == new.get(name):
            continue
        label = _LABELS.get(name, f"the {name}")
        if name == "key":
            said.append(f"{label} changed")
        else:
            said.append(f"{label} changed ({json.dumps(old.get(name))} -> {json.dumps(new.get(name))})")
    was = {i["path"]: i for i in old.get("inputs", []) if isinstance(i, dict) and "path" in i}
    now = {i["path"]: i for i in new.get("inputs", [])}
    gone, added = [p for p in was if p not in now], [p for p in now if p not in was]
    if gone or added:
        said.append("the inputs changed (" + ", ".join([*(f"{p} added" for p in added), *(f"{p} gone" for p in gone)])
                    + ")")
    for p, identity in now.items():
        if p in was and was[p] != identity:
            said.append(f"the input {p} changed (size or modification time)")
    return said


def write_manifest(path, entries: list, *, run: dict | None = None, **fields) -> None:
    """Record the outputs ``entries`` in the manifest at ``path``, atomically.

    Each entry replaces the one of the same output; the entries of the other outputs already
    recorded are kept (each with its run written out), so runs into one directory share its
    manifest. The read, merge and write hold an exclusive lock on the directory, so runs writing
    into it at the same time each add their outputs. A manifest that cannot be read is replaced.

    Args:
      path: the manifest file.
      entries: one {"output": path, "run": :func:`run_record` (or none: ``run``), ...} per output
        written or kept; the output's size and modification time are recorded here.
      run: the run record of every entry without one (a survey's).
      **fields: more of the run to record (a survey's resolved plan, counts and failures).

    Returns:
      None.

    Examples:
      >>> import os, tempfile
      >>> folder = tempfile.mkdtemp()
      >>> out = os.path.join(folder, "kept.ply")
      >>> open(out, "w").close()
      >>> record = run_record([], method="hkc", ratio=0.2)
      >>> write_manifest(os.path.join(folder, MANIFEST), [{"output": out, "run": record}])
      >>> reusable(read_manifest(os.path.join(folder, MANIFEST)), out, record)[0]
      True
    """
    path = os.fspath(path)
    with _locked(os.path.dirname(os.path.abspath(path))):
        _merge_manifest(path, entries, run, fields)


@contextlib.contextmanager
def _locked(directory: str):
    """Hold an exclusive lock on ``directory`` (``flock`` on the directory itself, so no file is left
    behind) while the body runs: the read, merge and write of its manifest by one run at a time. Where
    the platform has no ``flock`` (Windows) the body runs unlocked."""
    try:
        import fcntl
    except ImportError:
        yield
        return
    fd = os.open(directory, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # closing the descriptor releases the lock


def _merge_manifest(path: str, entries: list, run: dict | None, fields: dict) -> None:
    """:func:`write_manifest`'s read, merge and atomic write, run under the directory's lock."""
    from hgjax import __version__

    try:
        old = read_manifest(path)
    except ManifestError:
        old = {}
    recorded = {}
    for entry in old.get("outputs", []):
        if os.path.exists(entry["output"]):
            recorded[entry["output"]] = {**entry, "run": entry.get("run", old.get("run"))}
    for entry in entries:
        output = os.path.abspath(entry["output"])
        st = os.stat(output)
        recorded[output] = {**entry, "output": output, "bytes": st.st_size, "mtime_ns": st.st_mtime_ns}
    body = {"hgjax": __version__, **({} if run is None else {"run": run}), **fields,
            "outputs": list(recorded.values())}
    text = json.dumps(body, indent=2, default=_plan.jsonable).encode()
    io._atomic_write(os.path.abspath(path), lambda fh: fh.write(text))


@dataclasses.dataclass(frozen=True)
class _Source:
    """One file of a survey: its path, the global id of its first point, its point count, its exact bounds."""

    path: str
    start: int
    count: int
    lo: np.ndarray  # (3,) float64 per-axis minimum of its coordinates
    hi: np.ndarray  # (3,) float64 per-axis maximum


@dataclasses.dataclass(frozen=True)
class _Sources(_grid.Source):
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

    def cloud(self, origin: np.ndarray, lo: np.ndarray, hi: np.ndarray, tile, client) -> _Survey:
        """The survey tiled by the grid of ``tile`` (its census runs on ``client``)."""
        return _Survey(self, origin, lo, hi, tile, client)


class _Survey(_grid.Cloud):
    """A survey of files tiled as one cloud, read lazily: a tile reads its core and halo from the files its box meets.

    The grid and ownership are :class:`_grid.Cloud`'s. The client holds the files' records, each
    occupied tile's point count and the owners of the sampled ids (:func:`hgjax.neighbours.spatial.sample_ids`),
    taken by one census task per file; never the coordinates. :meth:`gather` reads, one chunk
    at a time, only the files whose exact bounds meet the tile's box, and of a COPC file only
    the octree nodes whose bounds meet it.
    """

    def __init__(self, sources: _Sources, origin: np.ndarray, lo: np.ndarray, hi: np.ndarray, tile: float | None,
                 client=None):
        self.origin, self.lo, self.hi, self.tile, self.files = origin, lo, hi, tile, sources.files
        self.source, self.keep, self._indices, self.n = None, False, {}, sources.n
        self.progress = sources.progress
        self.shape = (1, 1, 1) if tile is None else _grid.grid_shape(lo, hi, tile)
        wanted = spatial.sample_ids(self.n)
        counts, self._owners = {}, {}
        tick = _ticker("census", {i: f.count for i, f in enumerate(self.files)}) if self.progress else None
        for codes, sizes, gids, owner in _each(client, _census, range(len(self.files)), self, wanted, tick=tick):
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
    """Files of ``paths`` (files or glob patterns), in the order given, each once: a file reached again (the same
    path, a symlink or hard link to it, another spelling) is left out (:func:`hgjax.io.file_identity`)."""
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    found = {}
    for p in paths:
        p = os.fspath(p)
        matches = sorted(glob.glob(p)) if glob.has_magic(p) else [p]
        if not matches:
            raise ValueError(f"paths: the pattern {p!r} matches no file")
        for m in matches:
            found.setdefault(io.file_identity(m), m)
    if not found:
        raise ValueError("paths must name at least one file; got none")
    return list(found.values())


def _ticker(what: str, sizes: dict, unit: str = "points") -> _runners.Ticker:
    """The progress of one stage of a survey's files (:class:`hgjax.engine._runners.Ticker`)."""
    return _runners.Ticker(what, sizes, task="file", unit=unit, prefix="hgjax survey")


def _each(client, fn, items, *args, tick=None) -> list:
    """``[fn(item, *args) for item in items]``, as :func:`hgjax.engine._runners.map_tasks` runs it; ``tick(i)`` as the
    i-th ends."""
    if tick is None:
        return _runners.map_tasks(client, fn, items, *args)
    if client is None:
        out = []
        for i, item in enumerate(items):
            out.append(fn(item, *args))
            tick(i)
        return out
    futures = [client.submit(fn, item, *args, pure=False) for item in items]
    for i, f in enumerate(futures):
        f.add_done_callback(lambda _, i=i: tick(i))
    return client.gather(futures)


def _temporary(directory: str, name: str) -> str:
    """A new temporary file's path in ``directory``, named as :mod:`hgjax.io` names the temporaries of its writes
    (``.NAME.HOST.PID.HEX.tmp``), so that :func:`hgjax.io.remove_stale_temporaries` removes one a killed run left."""
    host = re.sub(r"[^A-Za-z0-9-]", "-", socket.gethostname())
    return os.path.join(directory, f".{name}.{host}.{os.getpid()}.{secrets.token_hex(6)}.tmp")


def _allocate(path: str, nbytes: int) -> None:
    """Create ``path`` with ``nbytes`` of disk allocated to it, so that a full disk raises :class:`OSError` (ENOSPC)
    here, not SIGBUS where a memory map of a sparse file is first written."""
    with open(path, "xb") as fh:
        try:
            if hasattr(os, "posix_fallocate"):
                try:
                    os.posix_fallocate(fh.fileno(), 0, nbytes)
                    return
                except OSError as err:
                    if err.errno not in (errno.EINVAL, errno.EOPNOTSUPP):
                        raise
            block = bytes(1 << 20)  # no allocation call here: write the zeros
            for start in range(0, nbytes, len(block)):
                fh.write(block[:nbytes - start])
            fh.flush()
        except OSError as err:
            raise OSError(err.errno, f"{err.strerror}: {os.path.dirname(path)} cannot hold the {nbytes} bytes of"
                          " the survey's float64 coordinates") from err


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


def resample_files(paths, out_dir, ratio: float, *, method: str = _registry.DEFAULT, tile: float | None = None, client=None,
                   key=None, keep_going: bool = False, skip_existing: bool = False, progress: bool = False,
                   on_stage=None, on_resume=None, **params) -> SurveyResult:
    """Resample a survey of files as one cloud, writing the kept points of each file beside the others.

    Global ids run in file order, then point order within each file, and the kept ids are
    exactly those of :func:`resample` on the concatenated cloud. A file reached twice (the
    same path, a symbolic or hard link to it, a glob matching it again) is read once, where it first comes.
    The survey is read lazily:
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
    memmap (24 bytes a point, on disk) in a hidden temporary file of ``out_dir`` instead
    (``.hgjax-survey-xyz.f8.HOST.PID.HEX.tmp``: removed when the run ends, interrupted included,
    and by the next run where a killed one left it, as :func:`hgjax.io.remove_stale_temporaries`
    does), and hold what they need per point in memory: ``voxel`` (its count-targeted edge search
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
      skip_existing: keep an output only where :func:`reusable` says so: the manifest in
        ``out_dir`` records it as it is, written by a run of the same method, ratio, tile,
        key (random methods), parameters, working dtype and hgjax version from the same
        inputs (paths, sizes, modification times); the others are written. With every
        output kept, nothing is read or computed.
      progress: report on stderr, a tqdm bar per stage where stderr is a terminal (and tqdm is
        installed), else plain lines: a first line as each stage starts (the check of the files,
        their census, each pass over the tiles, the copy to disk of a whole-cloud method, the
        writes), then the files or tiles done, the points done of the total, the rate and,
        once enough is done to tell (:class:`hgjax._progress.Rate`), the time left (``hgjax tiles:
        tile scores 3/12 tiles, 210k/1.2M points, 53k points/s, ETA 19 s``), at most one line a
        second. Under the command line, each pass (and, in this process, the rows of each tile's
        kernels) counts into its run's progress instead (:mod:`hgjax._progress`).
      on_stage: ``on_stage(name, seconds)``, called as each stage ends: ``"check"`` (headers and
        the read of every input), ``"copy"`` (a whole-cloud method's memmap), the engine's stages
        (:data:`hgjax.engine.STAGES`), ``"write"``.
      on_resume: ``on_resume(line)``, with ``skip_existing``: called once per output, before
        anything is read, with the line of :func:`reusable` saying it is kept or why it is
        recomputed.

    Returns:
      :class:`SurveyResult`. Each output holds its input's kept points in input order, with
      every attribute, and a LAS/LAZ output keeps its input's header (point format, scale,
      offset, extra dimensions); the output of a COPC input is a plain LAZ file of the same
      name (its octree VLRs are dropped: nothing here writes COPC). The outputs carry the
      fields of :func:`hgjax.cli`'s file-by-file outputs: with a scoring method, a ``score``
      column holding each kept point's score from this run (the value it was ranked by, as
      :func:`hgjax.tiles.resample` with ``return_scores`` gives it on the concatenated cloud;
      LHF's two lengths combined at the kept count), replacing a ``score`` attribute read from
      the input; a sampler's outputs carry the input's attributes as they are; a plain ``.npy``
      array's output is a plain array, without the score (:func:`hgjax.io.holds_scores`).
      ``out_dir/hgjax-manifest.json`` records the run (:func:`run_record`), the
      number of points N and kept M, each output's count, size and modification time, and under ``resolved`` what
      decided the kept set: the :class:`Plan` (origin, bounds, resolved build and score
      parameters, halo), the selection's global statistics (LHF's Gamma_a and Gamma_b,
      GFR's score sum) and the threshold (the last kept score and its global id), so a
      rerun can be checked against it; outputs and manifest are written atomically
      (:func:`write_manifest`: outputs of other runs recorded there are kept).

    Raises:
      ValueError: ``paths`` matches no file, or an output would be one of the inputs.
      ManifestError: with ``skip_existing``, the manifest in ``out_dir`` is not one.
      hgjax.io.PointCloudReadError: an input cannot be read (without ``keep_going``), before
        any output is written.
      TypeError, ValueError: as :func:`resample`.
    """
    import jax

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
    entry = _registry.entry(method)
    _run.checked_tile(entry, params, tile, client)  # a method that cannot be tiled is refused before any read
    record = run_record(files, method=method, ratio=ratio, key=key, params=params, tile=tile,
                        dtype="float64" if jax.config.jax_enable_x64 else "float32")
    manifest = os.path.join(out_dir, MANIFEST)
    if os.path.isdir(out_dir):
        io.remove_stale_temporaries(out_dir)
    done = set()
    if skip_existing:
        old = read_manifest(manifest)
        for p in files:
            reuse, line = reusable(old, targets[p], record)
            if on_resume is not None:
                on_resume(line)
            if reuse:
                done.add(p)
    if done and len(done) == len(files):
        return SurveyResult([], [targets[p] for p in files], {}, manifest)
    clock = time.perf_counter()
    failures, announced = {}, {}
    for p in files:  # headers first: a LAS/LAZ file whose header cannot be read fails before any coordinate is
        try:
            announced[p] = io.header_count(p)
        except io.PointCloudReadError as err:
            if not keep_going:
                raise
            failures[p] = str(err)
    sources, counts = [], {}
    tick = _ticker("check", {i: os.path.getsize(p) for i, p in enumerate(announced)}, "bytes") if progress else None
    checked = _each(client, _scan, [(os.path.abspath(p), c) for p, c in announced.items()], tick=tick)
    for p, got in zip(announced, checked):
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
    clock = _ended(on_stage, "check", clock)
    scoring = isinstance(entry, Method)
    lazily = entry.refused(params) is None if scoring else entry.ids is not None
    if progress and client is None and _progress.current() is not None and "progress" in entry.resample_params:
        params = {**params, "progress": True}  # the command line's run counts the rows of each tile's kernels
    if lazily:
        run = _run.run(survey, ratio, method=method, tile=tile, client=client, key=key, return_scores=scoring,
                         on_stage=on_stage, params=dict(params))
    else:  # the methods that need the whole cloud at once read it from a float64 memmap
        work = _temporary(out_dir, "hgjax-survey-xyz.f8")
        io.OPEN_TEMPORARIES.add(work)  # the command line removes it when a signal ends the process at once
        try:
            _allocate(work, n * 3 * np.dtype(np.float64).itemsize)
            disk = np.memmap(work, dtype=np.float64, mode="r+", shape=(n, 3))
            tick = _ticker("copy", dict(enumerate(counts.values()))) if progress else None
            for i, f in enumerate(sources):
                _stage(disk, f.start, f.path)
                if tick:
                    tick(i)
            disk.flush()
            _ended(on_stage, "copy", clock)
            run = _run.run(disk, ratio, method=method, tile=tile, client=client, key=key, return_scores=scoring,
                             on_stage=on_stage, params=dict(params))
            del disk
        finally:
            io.OPEN_TEMPORARIES.discard(work)
            with contextlib.suppress(FileNotFoundError):
                os.unlink(work)
    clock = time.perf_counter()
    kept = np.sort(run.idx)
    scores = None if run.scores is None else np.asarray(run.scores)
    written, skipped, outputs = [], [], {}
    tick = _ticker("write", {p: counts[p] for p in starts if p not in done}) if progress else None
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
            attributes = kept_data.attributes
            if scores is not None:  # the new score replaces one read back from an earlier output
                attributes = {k: v for k, v in attributes.items() if k != "score"}
            io.write_points(targets[p], kept_data.points, attributes=attributes, header=kept_data.header,
                            scores=None if scores is None else scores[start + local])
        except (io.PointCloudReadError, io.PointCloudWriteError, OSError, ValueError) as err:
            if not keep_going:
                raise
            failures[p] = str(err)
            del outputs[p]
            continue
        finally:
            if tick:
                tick(p)
        written.append(targets[p])
    resolved = {"plan": None if run.plan is None else run.plan.record(), "selection": run.selection,
                "threshold": run.threshold}
    write_manifest(manifest, list(outputs.values()), run=record, resolved=resolved, n=n, m=int(kept.size),
                   failures=failures)
    _ended(on_stage, "write", clock)
    return SurveyResult(written, skipped, failures, manifest)


def _ended(on_stage, name: str, start: float) -> float:
    """Report that stage ``name``, begun at ``start``, ended (``on_stage(name, seconds)``); the time now."""
    now = time.perf_counter()
    if on_stage is not None:
        on_stage(name, now - start)
    return now
