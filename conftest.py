"""Doctest settings: x64 on, as a research pipeline that wants float64 would run."""

import jax

jax.config.update("jax_enable_x64", True)
