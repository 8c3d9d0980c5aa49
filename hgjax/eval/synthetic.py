"""Edge-labelled clouds: unions of axis-aligned boxes, and the labelled real clouds.

The paper's edge benchmark (Sec. IV-A) samples "the external surface of models constructed
from combinations of cubes of various sizes" and labels the points on sharp edges. Here:

* A shape is a union of axis-aligned boxes with integer corners (so coplanar faces are
  exactly coplanar). Its OUTER surface is sampled in one of two regimes (``regime=``):

  - ``"random"`` (:func:`sample_box_union`): i.i.d. uniform points. Each box face is sampled
    in proportion to its area and a sample is rejected when the union continues on the
    outer side of the face (it lies inside another box or on a face shared with another
    box), or when an earlier box already owns the same patch of a coplanar face (overlapping
    boxes would otherwise sample it twice).
  - ``"grid"`` (:func:`grid_box_union`): the positions of a cubic lattice of spacing h on
    the surface, each once, as CAD exports and structured scans are. The paper's Table 1 is
    reproduced in this regime (REFERENCE.md, "Evaluation protocol"), with the edge band one
    spacing wide (``GRID_DELTA``).
* The sharp edges are exact. On the grid of all distinct box coordinates, a grid segment is
  a sharp edge when the four grid cells around it are occupied in a pattern that is not flat:
  one cell (convex edge), three cells (concave edge) or two diagonal cells. Two adjacent
  occupied cells (a seam between coplanar faces) or zero / four are not edges.
* A point is an edge point when its distance to the nearest sharp edge is at most
  ``delta * resolution`` (``delta`` is in units of the intrinsic resolution of the clean
  cloud, so the band is a fixed number of point spacings wide at any density).
* Noise is Gaussian with standard deviation ``noise * resolution`` on every coordinate; the
  labels stay those of the clean points. The noise directions come from a fixed stream of
  the seed, so a noise sweep scales one draw.
"""

from __future__ import annotations

import os
from typing import NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation

from hgjax import _validate
from hgjax.neighbours.spatial import intrinsic_resolution

__all__ = [
    "DEFAULT_DELTA",
    "DEFAULT_N_POINTS",
    "GRID_DELTA",
    "NOISE_LEVELS",
    "REGIMES",
    "EdgeCloud",
    "box_surface",
    "box_union_cloud",
    "grid_box_union",
    "grid_subdivisions",
    "load_labelled",
    "random_boxes",
    "sample_box_union",
    "sharp_edges",
    "synthetic_set",
]

DEFAULT_N_POINTS = 8000
DEFAULT_DELTA = 0.9
GRID_DELTA = 1.0
REGIMES = ("random", "grid")
NOISE_LEVELS = (0.0, 0.1, 0.2, 0.5, 1.0)
EDGE_SPACING = 0.25  # spacing of ``edge_points`` along the edges, in units of resolution

# Independent random streams of one seed: np.random.default_rng([seed, stream]).
_BOXES, _SAMPLES, _ROTATION, _NOISE = range(4)

# Colour labels of the PCEDNet ground-truth PLY files (RGB).
LABEL_EDGE = (168, 0, 0)
LABEL_NON_EDGE = (255, 255, 255)
LABEL_NEAR_EDGE = (255, 196, 93)


class EdgeCloud(NamedTuple):
    """A point cloud with ground-truth edge labels.

    Attributes:
      points: (N, 3) float64 coordinates (rotated and noisy when asked for).
      edge_mask: (N,) bool, True for edge points.
      edge_points: (E', 3) float64 points on the true sharp edges (samples every
        ``EDGE_SPACING`` resolutions along each edge for synthetic shapes; the labelled edge
        points for real clouds), in the same frame as ``points``.
      resolution: intrinsic resolution of the clean cloud.
      delta: absolute half-width of the edge band (0.0 for real clouds).
      name: a short description.

    Examples:
      >>> import hgjax
      >>> cloud = hgjax.eval.box_union_cloud(seed=0, n_points=1000)
      >>> cloud.points.shape, cloud.edge_mask.shape
      ((1000, 3), (1000,))
    """

    points: np.ndarray
    edge_mask: np.ndarray
    edge_points: np.ndarray
    resolution: float
    delta: float
    name: str


def _check_boxes(boxes) -> np.ndarray:
    b = np.asarray(boxes, dtype=np.float64)
    if b.ndim != 3 or b.shape[1:] != (2, 3) or b.shape[0] == 0:
        raise ValueError(f"boxes must have shape (B, 2, 3) with B >= 1 (lower, upper corners); got {b.shape}")
    if not (np.isfinite(b).all() and (b[:, 1] > b[:, 0]).all()):
        raise ValueError("boxes must be finite with upper corner > lower corner on every axis")
    return b


def _faces(boxes: np.ndarray):
    """Per face (B * 6): box index, normal axis, side (0 lower, 1 upper), area."""
    n_boxes = boxes.shape[0]
    box = np.repeat(np.arange(n_boxes), 6)
    axis = np.tile(np.repeat(np.arange(3), 2), n_boxes)
    side = np.tile([0, 1], 3 * n_boxes)
    size = boxes[:, 1] - boxes[:, 0]  # (B, 3)
    area = np.prod(size, axis=1)[box] / size[box, axis]
    return box, axis, side, area


def _outer(p: np.ndarray, box: np.ndarray, axis: np.ndarray, side: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """(M,) True where a face sample lies on the outer surface and its box owns the patch."""
    m = p.shape[0]
    rows = np.arange(m)
    lo, hi = boxes[:, 0][None], boxes[:, 1][None]  # (1, B, 3)
    q = p[:, None, :]  # (M, 1, 3)
    inside = (q > lo) & (q < hi)  # (M, B, 3) strict, per axis
    on_axis = q[rows, 0, axis][:, None]  # (M, 1) coordinate along the normal
    lo_a, hi_a = boxes[:, 0, axis].T, boxes[:, 1, axis].T  # (M, B)
    up = side[:, None] == 1
    # The union continues on the outer side when some box covers [x, x + eps) (upper face)
    # or (x - eps, x] (lower face) along the normal and the open square around it.
    beyond = np.where(up, (lo_a <= on_axis) & (on_axis < hi_a), (lo_a < on_axis) & (on_axis <= hi_a))
    tangent = np.ones((m, boxes.shape[0]), dtype=bool)
    for t in range(3):
        tangent &= np.where((axis != t)[:, None], inside[:, :, t], True)
    covered = (beyond & tangent).any(axis=1)
    # A coplanar face of the same orientation on an earlier box owns the same patch.
    plane = np.where(up, hi_a, lo_a) == on_axis
    earlier = np.arange(boxes.shape[0])[None] < box[:, None]
    closed = np.ones((m, boxes.shape[0]), dtype=bool)
    for t in range(3):
        closed &= np.where((axis != t)[:, None], (q[:, :, t] >= lo[..., t]) & (q[:, :, t] <= hi[..., t]), True)
    owned = (plane & earlier & closed).any(axis=1)
    return ~covered & ~owned


def _sample_surface(boxes: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """n i.i.d. uniform points on the outer surface of the union of ``boxes`` (rejection)."""
    box, axis, side, area = _faces(boxes)
    prob = area / area.sum()
    out, have = [], 0
    chunk = min(max(2 * n, 1024), 1 << 20)
    while have < n:
        f = rng.choice(box.size, size=chunk, p=prob)
        lo, hi = boxes[box[f], 0], boxes[box[f], 1]
        p = lo + rng.random((chunk, 3)) * (hi - lo)
        p[np.arange(chunk), axis[f]] = np.where(side[f, None] == 1, hi, lo)[np.arange(chunk), axis[f]]
        if boxes.shape[0] > 1:
            p = p[_outer(p, box[f], axis[f], side[f], boxes)]
        out.append(p)
        have += p.shape[0]
    return np.concatenate(out)[:n]


def _occupancy(boxes: np.ndarray):
    """The grid of distinct box coordinates and its padded cell occupancy.

    Returns:
      grid: three sorted arrays of the distinct coordinates per axis (X + 1, Y + 1, Z + 1).
      occ: (X + 2, Y + 2, Z + 2) bool, True for cells inside the union, with a layer of
        empty cells all around (grid node i sits between cells i and i + 1).
    """
    grid = [np.unique(boxes[:, :, a]) for a in range(3)]
    centres = [(g[1:] + g[:-1]) / 2 for g in grid]
    cx, cy, cz = np.meshgrid(*centres, indexing="ij")
    c = np.stack([cx, cy, cz], axis=-1)[..., None, :]  # (X, Y, Z, 1, 3)
    occ = ((c > boxes[:, 0]) & (c < boxes[:, 1])).all(axis=-1).any(axis=-1)
    return grid, np.pad(occ, 1)


def _surface_area(boxes: np.ndarray) -> float:
    """Area of the boundary of the union of ``boxes``: the cell faces between a full and an empty cell."""
    grid, occ = _occupancy(boxes)
    area = 0.0
    for a in range(3):
        t1, t2 = [t for t in range(3) if t != a]
        o = np.moveaxis(occ, (a, t1, t2), (0, 1, 2))[:, 1:-1, 1:-1]
        changed = o[1:] != o[:-1]  # (cells along a + 1, T1, T2)
        area += float((changed * np.outer(np.diff(grid[t1]), np.diff(grid[t2]))).sum())
    return area


def sharp_edges(boxes) -> np.ndarray:
    """The sharp edges of a union of axis-aligned boxes, exactly.

    Args:
      boxes: (B, 2, 3) lower and upper corners.

    Returns:
      (S, 2, 3) float64 segment end points. Convex, concave and non-manifold edges are
      included; seams between coplanar faces are not. Collinear edges may come as several
      consecutive segments.

    Raises:
      ValueError: if ``boxes`` has the wrong shape or an empty box.

    Examples:
      >>> import numpy as np
      >>> from hgjax.eval import sharp_edges
      >>> sharp_edges(np.array([[[0., 0, 0], [1, 1, 1]]])).shape
      (12, 2, 3)
      >>> two = np.array([[[0., 0, 0], [1, 1, 1]], [[1., 0, 0], [2, 1, 1]]])  # a 2 x 1 x 1 block
      >>> float(np.linalg.norm(np.diff(sharp_edges(two), axis=1), axis=-1).sum())
      16.0
    """
    grid, occ = _occupancy(_check_boxes(boxes))
    segments = []
    for a in range(3):
        t1, t2 = [t for t in range(3) if t != a]
        o = np.moveaxis(occ, (a, t1, t2), (0, 1, 2))[1:-1]  # (cells along a, T1 + 2, T2 + 2)
        q00, q10, q01, q11 = o[:, :-1, :-1], o[:, 1:, :-1], o[:, :-1, 1:], o[:, 1:, 1:]
        count = q00.astype(int) + q10 + q01 + q11
        diagonal = (count == 2) & (q00 == q11)
        i, j, k = np.nonzero((count == 1) | (count == 3) | diagonal)
        start = np.empty((i.size, 3))
        start[:, a], start[:, t1], start[:, t2] = grid[a][i], grid[t1][j], grid[t2][k]
        end = start.copy()
        end[:, a] = grid[a][i + 1]
        segments.append(np.stack([start, end], axis=1))
    return np.concatenate(segments)


def _distance_to_segments(points: np.ndarray, segments: np.ndarray, chunk: int = 4096) -> np.ndarray:
    """(N,) Euclidean distance from each point to the nearest of the (S, 2, 3) segments."""
    a, d = segments[:, 0], segments[:, 1] - segments[:, 0]
    dd = np.einsum("sk,sk->s", d, d)
    out = np.empty(points.shape[0])
    for s in range(0, points.shape[0], chunk):
        rel = points[s:s + chunk, None, :] - a[None]  # (C, S, 3)
        t = np.clip(np.einsum("csk,sk->cs", rel, d) / dd, 0.0, 1.0)
        out[s:s + chunk] = np.sqrt(((rel - t[..., None] * d) ** 2).sum(-1).min(axis=1))
    return out


def _points_on_segments(segments: np.ndarray, spacing: float) -> np.ndarray:
    """Points every ``spacing`` (at most) along each segment, both end points included."""
    length = np.linalg.norm(segments[:, 1] - segments[:, 0], axis=1)
    counts = np.ceil(length / spacing).astype(int) + 1
    t = np.concatenate([np.linspace(0.0, 1.0, c) for c in counts])
    seg = np.repeat(np.arange(segments.shape[0]), counts)
    return segments[seg, 0] + t[:, None] * (segments[seg, 1] - segments[seg, 0])


def sample_box_union(boxes, *, n_points: int = DEFAULT_N_POINTS, seed: int, delta: float = DEFAULT_DELTA,
                     rotate: bool = False, noise: float = 0.0, name: str = "boxes") -> EdgeCloud:
    """Sample the outer surface of a union of axis-aligned boxes and label its edge points.

    Args:
      boxes: (B, 2, 3) lower and upper corners of the boxes.
      n_points: N, the number of points (>= 2).
      seed: integer seed; the samples, the rotation and the noise draw come from independent
        streams of it, so changing ``rotate`` or ``noise`` keeps the same surface samples.
      delta: half-width of the edge band in units of the clean cloud's intrinsic
        resolution: a point is an edge point when its distance to the nearest sharp edge is
        at most ``delta * resolution``.
      rotate: apply a random rotation (from ``seed``) to the points and edge points.
      noise: p >= 0; Gaussian noise of standard deviation p * resolution is added to each
        coordinate (labels are those of the clean points).
      name: stored in the result.

    Returns:
      An :class:`EdgeCloud` with float64 ``points`` (N, 3).

    Raises:
      TypeError, ValueError: invalid boxes, n_points, seed, delta or noise.

    Examples:
      >>> import numpy as np
      >>> from hgjax.eval import sample_box_union
      >>> cloud = sample_box_union(np.array([[[0., 0, 0], [1, 1, 1]]]), n_points=500, seed=0)
      >>> cloud.points.shape, bool(cloud.edge_mask.any())
      ((500, 3), True)
    """
    boxes = _check_boxes(boxes)
    n_points = _validate.check_int(n_points, "n_points", minimum=2)
    seed = _validate.check_int(seed, "seed", minimum=0)
    delta = _validate.check_positive(delta, "delta")
    noise = _check_noise(noise)
    clean = _sample_surface(boxes, n_points, np.random.default_rng([seed, _SAMPLES]))
    resolution = intrinsic_resolution(clean)
    segments = sharp_edges(boxes)
    edge_mask = _distance_to_segments(clean, segments) <= delta * resolution
    return _finish(clean, edge_mask, segments, resolution, delta, seed=seed, rotate=rotate, noise=noise, name=name)


def _finish(clean: np.ndarray, edge_mask: np.ndarray, segments: np.ndarray, resolution: float, delta: float, *,
            seed: int, rotate: bool, noise: float, name: str) -> EdgeCloud:
    """Add the noise and the rotation (streams of ``seed``) to a labelled clean cloud."""
    edge_points = _points_on_segments(segments, EDGE_SPACING * resolution)
    points = clean
    if noise > 0:
        points = clean + noise * resolution * np.random.default_rng([seed, _NOISE]).standard_normal(clean.shape)
    if rotate:
        rot = Rotation.random(random_state=np.random.default_rng([seed, _ROTATION]))
        points, edge_points = rot.apply(points), rot.apply(edge_points)
    return EdgeCloud(points, edge_mask, edge_points, resolution, delta * resolution, name)


def _lattice_surface(cells: np.ndarray) -> np.ndarray:
    """(M, 3) int64 lattice points on the boundary of a union of boxes with integer corners.

    Every closed box face contributes its lattice points; a point is kept when at least one
    of the eight unit cells around it is outside the union (so hidden and shared faces drop
    out), and points where faces meet are kept once. Rows come sorted lexicographically.
    """
    faces = []
    for lo, hi in cells:
        ranges = [np.arange(lo[t], hi[t] + 1) for t in range(3)]
        for a in range(3):
            for plane in (lo[a], hi[a]):
                axes = [np.array([plane]) if t == a else ranges[t] for t in range(3)]
                faces.append(np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3))
    q = np.unique(np.concatenate(faces), axis=0)
    corners = np.stack(np.meshgrid(*[(-1, 1)] * 3, indexing="ij"), axis=-1).reshape(8, 3)
    centres = 2 * q[:, None, :] + corners  # (M, 8, 3) cell centres, doubled to stay integer
    lo2, hi2 = 2 * cells[:, 0], 2 * cells[:, 1]  # (B, 3)
    inside = ((centres[:, :, None] > lo2) & (centres[:, :, None] < hi2)).all(axis=-1).any(axis=-1)  # (M, 8)
    return q[~inside.all(axis=1)]


def grid_box_union(boxes, *, subdivisions: int, seed: int, delta: float = GRID_DELTA, rotate: bool = False,
                   noise: float = 0.0, name: str = "boxes") -> EdgeCloud:
    """Sample the outer surface of a union of boxes on a regular grid and label its edge points.

    The points are the positions of the cubic lattice of spacing h = 1 / ``subdivisions``
    that lie on the boundary of the union: faces hidden inside the union or shared between
    boxes carry no points, and a point where faces meet (edges, corners) appears once. Any
    two points are at least h apart and every point has a neighbour at h, so the intrinsic
    resolution is h. The rows are in a random order (from ``seed``), as a scanner would not
    sort them.

    Args:
      boxes: (B, 2, 3) lower and upper corners, multiples of h (e.g. integers).
      subdivisions: lattice steps per unit length (>= 1).
      seed: integer seed for the row order, the rotation and the noise (independent
        streams, as in :func:`sample_box_union`).
      delta: half-width of the edge band in spacings: a point is an edge point when its
        distance to the nearest sharp edge (convex or concave) is at most ``delta * h``.
        The default 1.0 labels the lattice row on each edge and the row next to it on
        either face.
      rotate: apply a random rotation (from ``seed``) to the points and edge points.
      noise: p >= 0; Gaussian noise of standard deviation p * h is added to each coordinate
        (labels are those of the clean points).
      name: stored in the result.

    Returns:
      An :class:`EdgeCloud` with float64 ``points`` (N, 3) and ``resolution`` = h.

    Raises:
      TypeError, ValueError: invalid boxes, a corner off the lattice, or an invalid
        subdivisions, seed, delta or noise.

    Examples:
      >>> import numpy as np
      >>> from hgjax.eval import grid_box_union
      >>> cloud = grid_box_union(np.array([[[0., 0, 0], [1, 1, 1]]]), subdivisions=4, seed=0)
      >>> cloud.points.shape, int(cloud.edge_mask.sum()), cloud.resolution  # 6 * 4**2 + 2 points
      ((98, 3), 92, 0.25)
    """
    boxes = _check_boxes(boxes)
    subdivisions = _validate.check_int(subdivisions, "subdivisions", minimum=1)
    seed = _validate.check_int(seed, "seed", minimum=0)
    delta = _validate.check_positive(delta, "delta")
    noise = _check_noise(noise)
    scaled = boxes * subdivisions
    cells = np.rint(scaled).astype(np.int64)
    if not np.allclose(scaled, cells, rtol=0.0, atol=1e-9):
        raise ValueError(f"box corners must be multiples of the spacing 1 / {subdivisions}")
    lattice = _lattice_surface(cells)
    lattice = lattice[np.random.default_rng([seed, _SAMPLES]).permutation(lattice.shape[0])]
    edge_mask = _distance_to_segments(lattice.astype(np.float64), sharp_edges(cells)) <= delta
    spacing = 1.0 / subdivisions
    return _finish(lattice / subdivisions, edge_mask, sharp_edges(boxes), spacing, delta, seed=seed, rotate=rotate,
                   noise=noise, name=name)


def _check_noise(noise) -> float:
    if isinstance(noise, (bool, np.bool_)) or not isinstance(noise, (int, float, np.integer, np.floating)):
        raise TypeError(f"noise must be a number >= 0; got {type(noise).__name__}")
    if not (np.isfinite(noise) and noise >= 0):
        raise ValueError(f"noise must be a finite number >= 0; got {noise!r}")
    return float(noise)


def random_boxes(seed: int) -> np.ndarray:
    """A union of 1 to 4 axis-aligned boxes with integer corners, from a seed.

    A base box (sides 2 to 6) gets up to three boxes standing on faces of the boxes already
    placed: each new box touches the face, covers part of it (possibly flush with one of
    its sides, giving coplanar seams) and may overhang it. Seed 0 is a single box; the others
    have concave junctions, convex edges and corners.

    Args:
      seed: integer >= 0.

    Returns:
      (B, 2, 3) float64 lower and upper corners.

    Examples:
      >>> from hgjax.eval import random_boxes
      >>> random_boxes(0).shape, random_boxes(1).shape[0] > 1
      ((1, 2, 3), True)
    """
    seed = _validate.check_int(seed, "seed", minimum=0)
    rng = np.random.default_rng([seed, _BOXES])
    size = rng.integers(2, 7, size=3)
    boxes = [np.stack([np.zeros(3), size.astype(float)])]
    n_extra = 0 if seed == 0 else 1 + (seed % 3)
    for _ in range(n_extra):
        base = boxes[rng.integers(len(boxes))]
        axis, side = int(rng.integers(3)), int(rng.integers(2))
        new = np.empty((2, 3))
        for t in range(3):
            if t == axis:
                height = float(rng.integers(1, 4))
                start = base[1, t] if side == 1 else base[0, t] - height
                new[:, t] = (start, start + height)
            else:
                lo, hi = base[:, t]
                width = float(rng.integers(1, max(int(hi - lo), 1) + 1))
                first = float(rng.integers(int(lo - width) + 1, int(hi)))  # overlap >= 1
                new[:, t] = (first, first + width)
        boxes.append(new)
    return np.stack(boxes)


def grid_subdivisions(boxes, n_points: int) -> int:
    """Lattice steps per unit that put about ``n_points`` grid points on the union's surface.

    Args:
      boxes: (B, 2, 3) lower and upper corners.
      n_points: the wanted number of points (>= 1).

    Returns:
      max(1, round(sqrt(n_points / A))) with A the area of the union's outer surface.

    Raises:
      TypeError, ValueError: invalid boxes or n_points.

    Examples:
      >>> import numpy as np
      >>> from hgjax.eval import grid_subdivisions
      >>> grid_subdivisions(np.array([[[0., 0, 0], [1, 1, 1]]]), 6000)  # 6 faces of 32 x 32
      32
    """
    n_points = _validate.check_int(n_points, "n_points", minimum=1)
    return max(1, round(float(np.sqrt(n_points / _surface_area(_check_boxes(boxes))))))


def box_union_cloud(*, seed: int, n_points: int = DEFAULT_N_POINTS, delta: float | None = None,
                    rotate: bool = False, noise: float = 0.0, regime: str = "random") -> EdgeCloud:
    """An edge-labelled cloud on the union of boxes :func:`random_boxes` makes from ``seed``.

    Args:
      seed: integer >= 0; sets the shape, the samples, the rotation and the noise.
      n_points: number of points N (``"random"``), or the approximate number (``"grid"``:
        the lattice of :func:`grid_subdivisions`).
      delta: edge band half-width in units of resolution. Default: ``DEFAULT_DELTA`` (0.9)
        for ``"random"``, which gives about the paper's 7.65 % edge points on average over
        :func:`synthetic_set` at the default N; ``GRID_DELTA`` (1.0, one spacing) for
        ``"grid"``.
      rotate: apply a random rotation (from ``seed``).
      noise: Gaussian noise std in units of resolution (paper's "10 %" read as 0.1).
      regime: ``"random"``, i.i.d. uniform samples (:func:`sample_box_union`), or
        ``"grid"``, lattice positions (:func:`grid_box_union`).

    Returns:
      An :class:`EdgeCloud` (see :func:`sample_box_union`, :func:`grid_box_union`).

    Raises:
      TypeError, ValueError: invalid arguments.

    Examples:
      >>> import hgjax
      >>> cloud = hgjax.eval.box_union_cloud(seed=1, n_points=2000)
      >>> cloud.points.shape, cloud.points.dtype, cloud.edge_mask.dtype
      ((2000, 3), dtype('float64'), dtype('bool'))
      >>> grid = hgjax.eval.box_union_cloud(seed=0, n_points=2000, regime="grid")
      >>> grid.name, grid.resolution
      ('grid-boxes0', 0.25)
    """
    regime = _validate.check_choice(regime, "regime", REGIMES)
    boxes = random_boxes(seed)
    if regime == "random":
        return sample_box_union(boxes, n_points=n_points, seed=seed, delta=DEFAULT_DELTA if delta is None else delta,
                                rotate=rotate, noise=noise, name=f"boxes{seed}")
    return grid_box_union(boxes, subdivisions=grid_subdivisions(boxes, n_points), seed=seed,
                          delta=GRID_DELTA if delta is None else delta, rotate=rotate, noise=noise,
                          name=f"grid-boxes{seed}")


def synthetic_set(*, n_shapes: int = 12, n_points: int = DEFAULT_N_POINTS, delta: float | None = None,
                  rotate: bool = False, noise: float = 0.0, regime: str = "random") -> list[EdgeCloud]:
    """The benchmark's fixed shapes: :func:`box_union_cloud` for seeds 0 .. n_shapes - 1.

    Args:
      n_shapes: number of shapes (>= 1).
      n_points, delta, rotate, noise, regime: as in :func:`box_union_cloud`.

    Returns:
      A list of ``n_shapes`` :class:`EdgeCloud`.

    Raises:
      TypeError, ValueError: invalid arguments.

    Examples:
      >>> import hgjax
      >>> [c.name for c in hgjax.eval.synthetic_set(n_shapes=2, n_points=300)]
      ['boxes0', 'boxes1']
    """
    n_shapes = _validate.check_int(n_shapes, "n_shapes", minimum=1)
    return [box_union_cloud(seed=s, n_points=n_points, delta=delta, rotate=rotate, noise=noise, regime=regime)
            for s in range(n_shapes)]


def box_surface(n: int, seed: int, *, size=(1.0, 0.8, 0.6)) -> np.ndarray:
    """n points drawn uniformly on the surface of one box (a test and benchmark cloud).

    Args:
      n: number of points (>= 1).
      seed: integer seed (>= 0).
      size: (3,) side lengths; the box spans [0, size].

    Returns:
      (n, 3) float64 points.

    Raises:
      TypeError, ValueError: invalid n, seed or size.

    Examples:
      >>> from hgjax.eval import box_surface
      >>> p = box_surface(1000, 0)
      >>> p.shape, p.dtype, bool((p.min(0) >= 0).all())
      ((1000, 3), dtype('float64'), True)
    """
    n = _validate.check_int(n, "n", minimum=1)
    seed = _validate.check_int(seed, "seed", minimum=0)
    box = _check_boxes(np.stack([np.zeros(3), np.asarray(size, dtype=np.float64)])[None])
    return _sample_surface(box, n, np.random.default_rng([seed, _SAMPLES]))


def load_labelled(path: str | os.PathLike, *, scheme: str = "auto") -> EdgeCloud:
    """Read a ground-truth PLY with colour-coded edge labels (PCEDNet or Bazazian et al.).

    Two colour schemes. PCEDNet (Himeur et al. 2022): (168, 0, 0) edge, (255, 255, 255)
    non-edge, (255, 196, 93) near-edge, which is counted as non-edge. Bazazian et al.
    (DICTA 2015, the EA / PCA-AC data): white (255, 255, 255) non-edge, any other colour
    (red, yellow) edge. ``scheme="auto"`` reads a file whose colours are all PCEDNet labels
    as PCEDNet and any other file as Bazazian.

    Args:
      path: a ``*.gt.ply`` point cloud with per-vertex RGB(A) colours.
      scheme: ``"auto"`` (default), ``"pcednet"`` or ``"bazazian"``.

    Returns:
      An :class:`EdgeCloud` with float64 points, ``edge_points`` = the edge points,
      ``resolution`` the intrinsic resolution and ``delta`` 0.0.

    Raises:
      ValueError: if the file has no colours, or (``"pcednet"``) a colour that is not one of
        its labels.

    Examples:
      >>> import pathlib, hgjax
      >>> path = pathlib.Path(hgjax.__file__).parents[2] / "shared/data/labelled/pced_twoplane90.gt.ply"
      >>> int(hgjax.eval.load_labelled(path).edge_mask.sum()) if path.exists() else 36
      36
    """
    import trimesh

    cloud = trimesh.load(path, file_type="ply")
    points = np.asarray(cloud.vertices, dtype=np.float64)
    colours = getattr(cloud, "colors", None)
    if colours is None or len(colours) != len(points):
        raise ValueError(f"{path} has no per-point colours to read the labels from")
    if scheme not in ("auto", "pcednet", "bazazian"):
        raise ValueError(f"scheme must be 'auto', 'pcednet' or 'bazazian'; got {scheme!r}")
    rgb = np.asarray(colours)[:, :3].astype(int)
    known = np.array([LABEL_EDGE, LABEL_NON_EDGE, LABEL_NEAR_EDGE])
    match = (rgb[:, None, :] == known[None]).all(-1)
    pcednet = bool(match.any(axis=1).all())
    if scheme == "pcednet" and not pcednet:
        bad = rgb[~match.any(axis=1)][0].tolist()
        raise ValueError(f"{path} has colour {bad}, not one of the labels {known.tolist()}")
    if scheme == "pcednet" or (scheme == "auto" and pcednet):
        edge_mask = match[:, 0]
    else:  # Bazazian et al.: any non-white colour is an edge
        edge_mask = ~(rgb == np.array(LABEL_NON_EDGE)).all(-1)
    name = os.path.basename(os.fspath(path)).removesuffix(".gt.ply")
    return EdgeCloud(points, edge_mask, points[edge_mask], intrinsic_resolution(points), 0.0, name)
