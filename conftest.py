"""Settings of every test and doctest: x64 on, as a research pipeline that wants float64 would run, and no
implicit rank promotion.

At the repository root, outside the package: pytest loads it for ``tests`` (an ancestor of every test file)
and for ``--pyargs hgjax`` run from the repository root, whose ``hgjax`` argument is anchored here (the
source tree's folder), whichever copy of the package, installed or not, the doctests are collected from.
"""

import jax

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")
