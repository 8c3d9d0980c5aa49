"""Files resampled as one cloud: :func:`resample_files` (one output per input) and the manifest of a run.

The public face of the engine's survey (:mod:`hgjax.engine._survey`, which says how): the kept
points are exactly those of :func:`hgjax.tiles.resample` on the concatenated cloud, and the
manifest (:data:`MANIFEST`) is the one resume rule of the command line's every mode.
"""

from hgjax.engine import (
    MANIFEST,
    ManifestError,
    SurveyResult,
    read_manifest,
    resample_files,
    reusable,
    run_record,
    write_manifest,
)

__all__ = ["MANIFEST", "ManifestError", "SurveyResult", "read_manifest", "resample_files", "reusable", "run_record",
           "write_manifest"]
