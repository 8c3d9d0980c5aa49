"""The paper's evaluation: edge-labelled synthetic clouds (box unions and meshed solids), edge
metrics, dense recovery."""

from hgjax.eval.synthetic import *  # noqa: F401,F403
from hgjax.eval.solids import *  # noqa: F401,F403
from hgjax.eval.metrics import *  # noqa: F401,F403
from hgjax.eval.recovery import *  # noqa: F401,F403
from hgjax.eval import metrics as _metrics, recovery as _recovery, solids, synthetic as _synthetic

__all__ = sorted(set(_synthetic.__all__) | set(solids.__all__) | set(_metrics.__all__) | set(_recovery.__all__))
