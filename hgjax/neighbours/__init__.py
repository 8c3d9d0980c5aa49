"""Neighbourhoods: which points each point's score reads, found on the host or traced in JAX.

One module per piece, each kind holding both of its backends (``search="host"``: a k-d tree on
NumPy; ``search="jax"``: a cell search traced in JAX, the same neighbours under ``jit``, ``vmap``
and ``grad``) behind one ``build``:

* the kinds: :mod:`~hgjax.neighbours.nearest` (k nearest: EA, PCA-AC, LHF, MSS),
  :mod:`~hgjax.neighbours.balls` (HKC/HKF's cubes and balls, the voxel spacing) and
  :mod:`~hgjax.neighbours.radius_graph` (GFR's graph; its traced build in
  :mod:`~hgjax.neighbours.traced_graph`);
* :mod:`~hgjax.neighbours.container`: the :class:`hgjax.Neighbourhoods` pytree every score reads;
* :mod:`~hgjax.neighbours.precision`: the host's local float frame and the working dtype;
* :mod:`~hgjax.neighbours.kdtree` and :mod:`~hgjax.neighbours.spatial`: the host's tree and its
  spatial index (every host query, Morton order, the sampled spacing);
* :mod:`~hgjax.neighbours.cells`: the traced search over sorted cells (k nearest, within a radius);
* :mod:`~hgjax.neighbours.backend`: which search runs, the traced frame, and the overflow guard.
"""
