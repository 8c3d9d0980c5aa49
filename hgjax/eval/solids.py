"""Edge-labelled clouds on triangle meshes of solids: the shapes beyond box unions.

Box unions (:mod:`hgjax.eval.synthetic`) have only 90-degree creases and no curved surface.
Here a solid is a closed triangle mesh, one of six families (:data:`FAMILIES`):

* ``"polytope"``: the convex hull of 5 to 14 random points (creases of every angle);
* ``"chamfered"``: a box with every edge cut at 45 degrees (135-degree creases, as a
  chamfer or a shallow bend) and its corners cut by triangles (35-degree creases);
* ``"filleted"``: a box with rounded edges and corners (radius 5 % to 30 % of the box): a
  smooth surface whose flat and curved parts meet without a crease;
* ``"prism"``: a star-shaped polygon of 3 to 9 corners extruded (convex and concave creases
  of every angle along the extrusion, 90-degree edges around the caps);
* ``"cylinder"``: a frustum of a cone (the cylinder when both radii agree): circular
  creases between the caps and a curved side;
* ``"sphere"``: no crease at all, curvature everywhere.

A mesh edge is a sharp edge when the normals of its two faces differ by at least
``SHARP_ANGLE`` (20 degrees); curved surfaces are tessellated finely enough (at most about 6
degrees between neighbouring faces) that they never reach it. A crease between
``AMBIGUOUS_ANGLE`` and ``SHARP_ANGLE`` is neither: points near it are marked in
``MeshCloud.ignore`` so that training can leave them out.

The surface is sampled in the two regimes of :mod:`hgjax.eval.synthetic`: i.i.d. uniform
points (``"random"``), or the positions of a square lattice laid on every plane of the mesh
(``"grid"``: the lattice of a plane depends only on the plane, so the triangles of one flat
face share it); or at a density that changes across the shape, as a scanner's falls with range
(``"varying"``: of 4 N uniform points, N kept without replacement with probability proportional
to ``DENSITY_RATIO`` ** t, t in [-1/2, 1/2] the position along a random direction); or evenly,
as the Poisson-disk samplers that turn meshes into clouds do (``"even"``: trimesh's
``sample_surface_even``: 3 N uniform points thinned until none is within sqrt(area / 3 N) of
another, the first N kept; blue noise, whose nearest-neighbour distances vary far less than
i.i.d. points'). Noise is
Gaussian, of standard deviation ``noise`` x the clean cloud's intrinsic resolution, on every
coordinate (``"iso"``) or along the surface normal (``"normal"``); labels are those of the clean
points. Everything comes from one seed.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from hgjax import _validate
from hgjax.eval.synthetic import DEFAULT_DELTA, GRID_DELTA, REGIMES, _check_noise, _distance_to_segments
from hgjax.neighbours.spatial import intrinsic_resolution

__all__ = ["AMBIGUOUS_ANGLE", "DENSITY_RATIO", "FAMILIES", "MESH_REGIMES", "NOISE_KINDS", "SHARP_ANGLE", "MeshCloud",
           "mesh_cloud", "random_solid", "solid_cloud"]

FAMILIES = ("polytope", "chamfered", "filleted", "prism", "cylinder", "sphere")
NOISE_KINDS = ("iso", "normal")
SHARP_ANGLE = np.deg2rad(20.0)  # angle between face normals from which a mesh edge is sharp
AMBIGUOUS_ANGLE = np.deg2rad(10.0)  # creases between this and SHARP_ANGLE are left unlabelled
SECTIONS = 64  # segments of a circle
MESH_REGIMES = REGIMES + ("varying", "even")
DENSITY_RATIO = 8.0  # "varying": the densest side's density over the sparsest's

# Independent random streams of one seed: np.random.default_rng([seed, stream]).
_SHAPE, _SAMPLES, _ROTATION, _NOISE = range(4)


class MeshCloud(NamedTuple):
    """A labelled cloud sampled from a mesh.

    Attributes:
      points: (N, 3) float64 coordinates (rotated and noisy when asked for).
      edge_mask: (N,) bool, True within ``delta`` x resolution of a sharp edge.
      ignore: (N,) bool, True within ``delta`` x resolution of a crease between
        ``AMBIGUOUS_ANGLE`` and ``SHARP_ANGLE`` and not an edge point.
      resolution: intrinsic resolution of the clean cloud.
      name: a short description.

    Examples:
      >>> from hgjax.eval import solids
      >>> cloud = solids.solid_cloud(seed=0, family="sphere", n_points=1000)
      >>> cloud.points.shape, int(cloud.edge_mask.sum())
      ((1000, 3), 0)
    """

    points: np.ndarray
    edge_mask: np.ndarray
    ignore: np.ndarray
    resolution: float
    name: str


def _circle(radius: float, z: float) -> np.ndarray:
    t = np.linspace(0.0, 2 * np.pi, SECTIONS, endpoint=False)
    return np.stack([radius * np.cos(t), radius * np.sin(t), np.full(SECTIONS, z)], axis=1)


def _prism(rng: np.random.Generator) -> trimesh.Trimesh:
    """A polygon star-shaped about the origin (corners at random angles and radii) extruded along z."""
    m = int(rng.integers(3, 10))
    gaps = rng.uniform(0.6, 1.0, m)  # every gap below pi: the origin sees every side
    angle = rng.uniform(0, 2 * np.pi) + 2 * np.pi * np.cumsum(gaps) / gaps.sum()
    radius = rng.uniform(0.4, 1.0, m)
    ring = np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=1)
    height = rng.uniform(0.3, 1.5)
    bottom = np.column_stack([ring, np.zeros(m)])
    top = np.column_stack([ring, np.full(m, height)])
    vertices = np.concatenate([bottom, top, [[0, 0, 0], [0, 0, height]]])
    i, j = np.arange(m), (np.arange(m) + 1) % m
    faces = np.concatenate([
        np.stack([i, j, j + m], 1), np.stack([i, j + m, i + m], 1),  # sides
        np.stack([np.full(m, 2 * m), j, i], 1), np.stack([np.full(m, 2 * m + 1), i + m, j + m], 1)])  # caps (fans)
    return trimesh.Trimesh(vertices, faces, process=True)


def random_solid(seed: int, family: str) -> trimesh.Trimesh:
    """A closed mesh of the given family (module docstring), from a seed.

    Args:
      seed: integer >= 0.
      family: one of :data:`FAMILIES`.

    Returns:
      A watertight ``trimesh.Trimesh``, about unit size.

    Raises:
      TypeError, ValueError: invalid seed or family.

    Examples:
      >>> from hgjax.eval import solids
      >>> [solids.random_solid(0, f).is_watertight for f in solids.FAMILIES]
      [True, True, True, True, True, True]
    """
    seed = _validate.check_int(seed, "seed", minimum=0)
    family = _validate.check_choice(family, "family", FAMILIES)
    rng = np.random.default_rng([seed, _SHAPE, FAMILIES.index(family)])
    if family == "polytope":
        return trimesh.convex.convex_hull(rng.standard_normal((int(rng.integers(5, 15)), 3)) * rng.uniform(0.5, 1, 3))
    if family == "prism":
        return _prism(rng)
    if family == "sphere":
        return trimesh.creation.icosphere(subdivisions=4, radius=rng.uniform(0.5, 1.0))
    if family == "cylinder":
        r0, r1 = rng.uniform(0.3, 1.0, 2)
        if rng.random() < 0.5:
            r1 = r0
        return trimesh.convex.convex_hull(np.concatenate([_circle(r0, 0.0), _circle(r1, rng.uniform(0.3, 1.5))]))
    size = rng.uniform(0.5, 1.5, 3)
    corners = np.stack(np.meshgrid(*[(0.0, 1.0)] * 3, indexing="ij"), -1).reshape(8, 3) * size
    if family == "chamfered":
        cut = rng.uniform(0.08, 0.3) * size.min()
        inward = np.where(corners > 0, -1.0, 1.0)
        moved = corners[:, None, :] + cut * inward[:, None, :] * (1 - np.eye(3))[None]  # (8, 3, 3): two axes moved
        return trimesh.convex.convex_hull(moved.reshape(-1, 3))
    radius = rng.uniform(0.05, 0.3) * size.min()
    ball = trimesh.creation.icosphere(subdivisions=4, radius=radius).vertices
    centres = radius + corners * (size - 2 * radius) / size
    return trimesh.convex.convex_hull((centres[:, None, :] + ball[None]).reshape(-1, 3))


def _creases(mesh: trimesh.Trimesh, low: float) -> np.ndarray:
    """(S, 2, 3) mesh edges whose face normals differ by at least ``low`` radians."""
    keep = mesh.face_adjacency_angles >= low
    return mesh.vertices[mesh.face_adjacency_edges[keep]]


def _grid(mesh: trimesh.Trimesh, spacing: float, rng: np.random.Generator):
    """Lattice positions of spacing ``spacing`` on every plane of the mesh, and their faces.

    The lattice of a plane is spanned by its unit normal's frame (u along the world axis
    least aligned with the normal, projected) through a random origin of the cloud, so
    coplanar triangles share it; a point on an edge between coplanar faces is kept once.
    """
    origin = rng.uniform(0, spacing, 3)
    points, faces = [], []
    for f, (tri, n) in enumerate(zip(mesh.triangles, mesh.face_normals)):
        axis = np.eye(3)[np.argmin(np.abs(n))]
        u = axis - (axis @ n) * n
        u /= np.linalg.norm(u)
        v = np.cross(n, u)
        base = origin + ((tri[0] - origin) @ n) * n  # the lattice origin, on the face's plane
        uv = np.stack([(tri - base) @ u, (tri - base) @ v], 1) / spacing
        lo, hi = np.floor(uv.min(0)).astype(int), np.ceil(uv.max(0)).astype(int)
        gi, gj = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1), indexing="ij")
        q = np.stack([gi.ravel(), gj.ravel()], 1).astype(float)
        a, b, c = uv
        m = np.stack([b - a, c - a], 1)
        if abs(np.linalg.det(m)) < 1e-12:
            continue
        w = np.linalg.solve(m, (q - a).T).T
        inside = (w[:, 0] >= -1e-9) & (w[:, 1] >= -1e-9) & (w.sum(1) <= 1 + 1e-9)
        points.append(base + spacing * (q[inside, :1] * u + q[inside, 1:] * v))
        faces.append(np.full(int(inside.sum()), f))
    points, faces = np.concatenate(points), np.concatenate(faces)
    _, first = np.unique(np.round(points / (1e-6 * spacing)), axis=0, return_index=True)
    first = np.sort(first)
    order = rng.permutation(first.size)
    return points[first][order], faces[first][order]


def _varying(mesh: trimesh.Trimesh, n: int, rng: np.random.Generator):
    """``n`` points of the surface and their faces at a density ``DENSITY_RATIO`` times higher on one side
    than on the other (module docstring)."""
    points, faces = trimesh.sample.sample_surface(mesh, 4 * n, seed=rng)
    along = points @ Rotation.random(random_state=rng).apply([1.0, 0.0, 0.0])
    t = (along - along.min()) / max(float(np.ptp(along)), np.finfo(float).tiny) - 0.5
    weight = DENSITY_RATIO ** t
    kept = np.sort(rng.choice(points.shape[0], n, replace=False, p=weight / weight.sum()))
    return points[kept], faces[kept]


def mesh_cloud(mesh: trimesh.Trimesh, *, n_points: int, seed: int, regime: str = "random", noise: float = 0.0,
               noise_kind: str = "iso", rotate: bool = True, delta: float | None = None,
               name: str = "mesh") -> MeshCloud:
    """Sample a closed mesh, label its sharp-edge points, add noise and a rotation.

    Args:
      mesh: a ``trimesh.Trimesh``.
      n_points: N (``"random"``, ``"varying"``) or the approximate N (``"grid"``, spacing sqrt(area / N);
        ``"even"``, at most N).
      seed: integer seed of the samples, the noise and the rotation (independent streams).
      regime: ``"random"``, ``"grid"``, ``"varying"`` or ``"even"`` (module docstring).
      noise: p >= 0, the noise's standard deviation in clean resolutions.
      noise_kind: ``"iso"`` or ``"normal"``.
      rotate: apply a random rotation (from ``seed``).
      delta: edge band half-width in resolutions; default 0.9 (random, varying, even) or 1.0 (grid), as
        :func:`hgjax.eval.box_union_cloud`.
      name: stored in the result.

    Returns:
      A :class:`MeshCloud`.

    Raises:
      TypeError, ValueError: invalid arguments.

    Examples:
      >>> import trimesh
      >>> from hgjax.eval import solids
      >>> cloud = solids.mesh_cloud(trimesh.creation.box(), n_points=2000, seed=0)
      >>> cloud.points.shape, bool(cloud.edge_mask.any()), bool(cloud.ignore.any())
      ((2000, 3), True, False)
    """
    n_points = _validate.check_int(n_points, "n_points", minimum=2)
    seed = _validate.check_int(seed, "seed", minimum=0)
    regime = _validate.check_choice(regime, "regime", MESH_REGIMES)
    noise_kind = _validate.check_choice(noise_kind, "noise_kind", NOISE_KINDS)
    noise = _check_noise(noise)
    delta = (GRID_DELTA if regime == "grid" else DEFAULT_DELTA) if delta is None else _validate.check_positive(
        delta, "delta")
    rng = np.random.default_rng([seed, _SAMPLES])
    if regime == "random":
        clean, face = trimesh.sample.sample_surface(mesh, n_points, seed=rng)
    elif regime == "grid":
        clean, face = _grid(mesh, float(np.sqrt(mesh.area / n_points)), rng)
    elif regime == "even":
        clean, face = trimesh.sample.sample_surface_even(mesh, n_points, seed=rng)
    else:
        clean, face = _varying(mesh, n_points, rng)
    resolution = intrinsic_resolution(clean)
    sharp = _creases(mesh, SHARP_ANGLE)
    edge = _distance_to_segments(clean, sharp) <= delta * resolution if len(sharp) else np.zeros(len(clean), bool)
    vague = mesh.vertices[mesh.face_adjacency_edges[(mesh.face_adjacency_angles >= AMBIGUOUS_ANGLE)
                                                    & (mesh.face_adjacency_angles < SHARP_ANGLE)]]
    ignore = ~edge & (_distance_to_segments(clean, vague) <= delta * resolution if len(vague) else False)
    points = clean
    if noise > 0:
        draw = np.random.default_rng([seed, _NOISE])
        if noise_kind == "iso":
            points = clean + noise * resolution * draw.standard_normal(clean.shape)
        else:
            points = clean + noise * resolution * draw.standard_normal((len(clean), 1)) * mesh.face_normals[face]
    if rotate:
        points = Rotation.random(random_state=np.random.default_rng([seed, _ROTATION])).apply(points)
    return MeshCloud(points, edge, np.asarray(ignore, bool), resolution, name)


def solid_cloud(*, seed: int, family: str, n_points: int, regime: str = "random", noise: float = 0.0,
                noise_kind: str = "iso", rotate: bool = True) -> MeshCloud:
    """:func:`mesh_cloud` on :func:`random_solid` ``(seed, family)``, named after both.

    Args:
      seed: integer >= 0; sets the shape, the samples, the noise and the rotation.
      family: one of :data:`FAMILIES`.
      n_points, regime, noise, noise_kind, rotate: as in :func:`mesh_cloud`.

    Returns:
      A :class:`MeshCloud`.

    Raises:
      TypeError, ValueError: invalid arguments.

    Examples:
      >>> from hgjax.eval import solids
      >>> c = solids.solid_cloud(seed=1, family="chamfered", n_points=3000, regime="grid", noise=0.5)
      >>> c.name, bool(c.edge_mask.any())
      ('grid-chamfered1', True)
    """
    return mesh_cloud(random_solid(seed, family), n_points=n_points, seed=seed, regime=regime, noise=noise,
                      noise_kind=noise_kind, rotate=rotate, name=f"{'grid-' if regime == 'grid' else ''}{family}{seed}")
