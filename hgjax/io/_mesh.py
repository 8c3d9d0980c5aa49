"""Meshes and whatever else trimesh loads (OBJ, OFF, GLB, glTF, ...), and STL with its size check.

A mesh is read as ``samples`` seeded surface samples with their face normals; a point cloud
trimesh loads keeps its vertices (and a PLY's every vertex property).
"""

from __future__ import annotations

import os

import numpy as np

from hgjax.io._errors import PointCloudReadError


def _read_trimesh(path: str, samples: int, seed: int) -> tuple[dict[str, np.ndarray], None, bool]:
    """(columns, no header, whether they are samples of a mesh) of any file trimesh loads; another
    extension is refused, naming those that are read."""
    import trimesh

    loaded = trimesh.available_formats()
    if not any(path.lower().endswith(f".{kind}") for kind in loaded):
        from hgjax.io import _FORMATS

        meshes = sorted(f".{kind}" for kind in loaded if kind.isalpha() and f".{kind}" not in _FORMATS
                        and kind != "zip")  # archives of meshes are read too, but are not a format to name
        extension = os.path.splitext(path)[1]
        what = f"{extension} files" if extension else "files without an extension"
        raise PointCloudReadError(f"cannot read {path}: hgjax does not read {what}; give one of"
                                  f" {', '.join(list(_FORMATS) + meshes)}")
    geometry = trimesh.load(path)
    if isinstance(geometry, trimesh.Scene):
        if not geometry.geometry:
            raise PointCloudReadError(f"cannot read {path}: no mesh or points found")
        geometry = trimesh.load(path, force="mesh")
    if isinstance(geometry, trimesh.Trimesh) and len(geometry.faces) > 0:
        samples_xyz, face = trimesh.sample.sample_surface(geometry, samples, seed=seed)
        columns = dict(zip("xyz", np.asarray(samples_xyz, np.float64).T))
        columns.update(zip(("nx", "ny", "nz"), np.asarray(geometry.face_normals[face]).T))
        return columns, None, True
    raw = getattr(geometry, "metadata", {}).get("_ply_raw", {}).get("vertex", {}).get("data")
    if raw is not None:  # PLY point cloud: keep every vertex property (ascii gives a dict)
        names = raw.dtype.names if isinstance(raw, np.ndarray) else tuple(raw)
        return {name: np.asarray(raw[name]).reshape(len(raw[name]), -1).squeeze(1) for name in names}, None, False
    vertices = np.asarray(getattr(geometry, "vertices", np.zeros((0, 3))), np.float64).reshape(-1, 3)
    columns = dict(zip("xyz", vertices.T))
    colors = np.asarray(getattr(geometry, "colors", ()))
    if colors.shape == (len(vertices), 4):
        columns.update(zip(("red", "green", "blue", "alpha"), colors.T))
    return columns, None, False


def _read_stl(path: str, samples: int, seed: int) -> tuple[dict[str, np.ndarray], None, bool]:
    """Surface samples of an STL mesh; a binary STL whose size disagrees with its triangle count is refused."""
    size = os.path.getsize(path)
    with open(path, "rb") as fh:
        head = fh.read(1024)
    announced = int.from_bytes(head[80:84], "little") if len(head) >= 84 else None
    binary = announced is not None and size == 84 + 50 * announced
    ascii_text = head.lstrip()[:5].lower() == b"solid" and b"\0" not in head and (b"facet" in head or size <= 1024)
    if not binary and not ascii_text:
        found = "" if announced is None else f": its header announces {announced} triangles ({84 + 50 * announced} bytes)"
        raise PointCloudReadError(f"cannot read {path}: truncated or corrupt binary STL{found}; the file holds"
                                  f" {size} bytes")
    return _read_trimesh(path, samples, seed)
