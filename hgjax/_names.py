"""The names of the registered methods, importable without NumPy or JAX.

:mod:`hgjax.engine._registry` takes its default from here and refuses method entries whose names
differ from these; the command line builds its parser from them before the engine is
imported, so that ``hgjax --help`` answers at once.
"""

SCORING = ("ea", "gfr", "hkc", "hkf", "lhf", "mss", "pca_ac")
"""The methods that score points (:class:`hgjax.Method`), sorted."""
SAMPLERS = ("fps", "uniform", "voxel")
"""The methods that only select points (:class:`hgjax.Sampler`), sorted."""
METHODS = tuple(sorted(SCORING + SAMPLERS))
"""The keys of :data:`hgjax.METHODS`, sorted."""
DEFAULT = "hkc"
"""The method of :func:`hgjax.resample`, :func:`hgjax.tiles.resample` and the command line when none is named."""
