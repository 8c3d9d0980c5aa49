"""The engine of every resample: plan -> tiles -> neighbourhoods -> score -> global selection.

One room, its modules private but :mod:`hgjax.engine.select`; the rest of the package asks the
engine only for the names below (each loaded on first use, as :mod:`hgjax` loads its own).

* :mod:`hgjax.engine._run`: the composition, :func:`run` (behind :func:`hgjax.resample`,
  :func:`hgjax.tiles.resample`, :func:`hgjax.survey.resample_files` and the command line).
* :mod:`hgjax.engine._registry`: :data:`METHODS`, the methods' entries by name.
* :mod:`hgjax.engine._pipeline`: the public pieces on one cloud, ``keep(score(neighbourhoods()))``.
* :mod:`hgjax.engine._plan`: :class:`Plan`, every whole-cloud decision made once.
* :mod:`hgjax.engine._grid`: the tiled cloud (:class:`Cloud`, a lazy :class:`Source`) and each
  tile scored on its core with a verified halo (:func:`tile_scores`).
* :mod:`hgjax.engine._runners`: where the tiles run, here or on Dask workers.
* :mod:`hgjax.engine._passes`: a method's two passes over the tiles with a global reduction between
  them (:class:`hgjax._method.Passes`); the engine decides where each tile's state waits.
* :mod:`hgjax.engine._sampled`: a sampler in tiles (:class:`hgjax._method.SampleTiles`) or from the
  point count.
* :mod:`hgjax.engine.select`: the selection, public (:func:`hgjax.top_k`, ...) and global (the top
  pairs of every tile from histograms of order-preserving keys).
* :mod:`hgjax.engine._survey`: files as one cloud, and the manifest of a run.
"""

import lazy_loader

_EXPORTS = {
    "_run": ["STAGES", "Run", "checked_tile", "first_stage", "keeps_top", "planned", "resample", "run", "searched"],
    "_registry": ["DEFAULT", "METHODS", "entry"],
    "_pipeline": ["capacity", "keep", "neighbourhoods", "score", "soft_resample", "soft_score", "soft_weights"],
    "_plan": ["Plan"],
    "_grid": ["Cloud", "Source", "tile_scores"],
    "_survey": ["MANIFEST", "ManifestError", "SurveyResult", "read_manifest", "resample_files", "reusable",
                "run_record", "write_manifest"],
}
__getattr__, __dir__, __all__ = lazy_loader.attach(__name__, submod_attrs=_EXPORTS)
