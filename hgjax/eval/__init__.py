"""The paper's evaluation: edge-labelled synthetic clouds, edge metrics, dense recovery."""

from hgjax.eval.synthetic import *  # noqa: F401,F403
from hgjax.eval.metrics import *  # noqa: F401,F403
from hgjax.eval.recovery import *  # noqa: F401,F403
from hgjax.eval import metrics as _metrics, recovery as _recovery, synthetic as _synthetic

__all__ = sorted(set(_synthetic.__all__) | set(_metrics.__all__) | set(_recovery.__all__))
