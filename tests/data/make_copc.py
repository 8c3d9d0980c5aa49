"""Write tests/data/survey.copc.laz: a tiny COPC file for the survey tests (run once; the output is committed).

The fixture is 4,000 points of hgjax's box-union surface scaled to 50 m, at UTM-like offsets
(500000, 4000000, 0) with scales (0.01, 0.01, 0.001), point format 6 with one uint8 extra
dimension ``quality``, in a three-level octree whose nodes are stored in shuffled key order
(so file order is not octree order) and whose level-1 nodes head child hierarchy pages
holding their level-2 children.
Nothing in hgjax writes COPC; this script uses copclib (copc-lib's Python bindings), which is
not a dependency of hgjax. Install it outside the project and run:

    pip install --target /tmp/copclib_pkg copclib==2.6.3
    PYTHONPATH=/tmp/copclib_pkg:. python tests/data/make_copc.py

Reruns write the same points, header and nodes; copclib may store the hierarchy entries in
another order. copclib names extra-bytes fields FIELD_0, FIELD_1, ...; the script renames
the field in place (the same 32-byte name slot of the extra-bytes VLR).
"""

import os

import laspy
import numpy as np

import hgjax

OFFSET = np.array([500000.0, 4000000.0, 0.0])
SCALE = np.array([0.01, 0.01, 0.001])
N, LEVELS = 4000, 3
PATH = os.path.join(os.path.dirname(os.path.abspath(__file__)), "survey.copc.laz")


def _records(xyz: np.ndarray) -> np.ndarray:
    """(N,) laspy point records of format 6 + ``quality`` (uint8) at the fixture's scale and offset."""
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.offsets, header.scales = OFFSET, SCALE
    header.add_extra_dims([laspy.ExtraBytesParams("FIELD_0", np.uint8)])
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz.T
    n = xyz.shape[0]
    las.intensity = (np.arange(n) * 7 % 65536).astype(np.uint16)
    las.return_number, las.number_of_returns = np.ones(n, np.uint8), np.ones(n, np.uint8)
    las.classification = (np.arange(n) % 3 + 1).astype(np.uint8)
    las.gps_time = np.arange(n, dtype=np.float64) * 0.5
    las["FIELD_0"] = (np.arange(n) % 251).astype(np.uint8)
    return las.points.array


def main() -> None:
    import copclib  # here, so collecting this file (pytest --doctest-modules) needs no copclib

    cloud = hgjax.eval.box_union_cloud(seed=11, n_points=N).points * 50 + OFFSET
    xyz = np.round((cloud - OFFSET) / SCALE) * SCALE + OFFSET  # exactly representable at the file's scale
    lo, hi = xyz.min(axis=0), xyz.max(axis=0)
    center, halfsize = (lo + hi) / 2, float((hi - lo).max()) / 2 + 1.0
    i = np.arange(N)
    level = np.where(i % 20 == 0, 0, np.where(i % 4 == 0, 1, 2))
    side = 2 * halfsize / 2.0 ** level
    cell = np.clip(np.floor((xyz - (center - halfsize)) / side[:, None]).astype(np.int64), 0,
                   (2 ** level - 1)[:, None])
    keys = sorted({(int(d), *map(int, c)) for d, c in zip(level, cell)})
    order = np.random.default_rng(5).permutation(len(keys))
    records = _records(xyz)

    eb = copclib.EbVlr(1)
    config = copclib.CopcConfigWriter(6, copclib.Vector3(*SCALE), copclib.Vector3(*OFFSET), "", eb, False)
    info = config.copc_info
    info.center_x, info.center_y, info.center_z = center
    info.halfsize, info.spacing = halfsize, 2 * halfsize / 8
    header = config.las_header
    header.min, header.max = copclib.Vector3(*lo), copclib.Vector3(*hi)
    writer = copclib.FileWriter(PATH, config)
    for j in order:
        d, x, y, z = keys[j]
        rows = np.flatnonzero((level == d) & (cell == (x, y, z)).all(axis=1))
        page = {0: (0, 0, 0, 0), 1: (1, x, y, z), 2: (1, x >> 1, y >> 1, z >> 1)}[d]
        if page not in keys:  # a page holds the node of its own key (laspy loops on a page without it)
            page = (0, 0, 0, 0)
        page = copclib.VoxelKey(*page)
        data = copclib.VectorChar(np.frombuffer(records[rows].tobytes(), np.int8))  # copclib takes signed bytes
        writer.AddNode(copclib.VoxelKey(d, x, y, z), data, page)
    writer.Close()

    with open(PATH, "rb") as fh:
        data = bytearray(fh.read())
    slot = data.index(b"FIELD_0".ljust(32, b"\0"))
    data[slot:slot + 32] = b"quality".ljust(32, b"\0")
    with open(PATH, "wb") as fh:
        fh.write(bytes(data))
    print(f"wrote {PATH}: {N} points, {len(keys)} nodes, {os.path.getsize(PATH)} bytes")


if __name__ == "__main__":
    main()
