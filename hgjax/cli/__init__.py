"""The ``hgjax`` command line: resample, score, compare and demo.

Every method comes from the registry :data:`hgjax.METHODS`: its neighbourhood kind, which
end of the score is kept, whether it draws random numbers and which ``-p NAME=VALUE``
parameters it takes. A scoring method is run as ``neighbourhoods -> score -> keep``, so
the score is computed once and written next to the kept points.

Points are read in float64 and moved to their local frame (:func:`hgjax.local_frame`) in
float64 before the library sees them, so georeferenced scans (UTM coordinates of 1e6 m)
keep their millimetres with every method; outputs keep the original coordinates.
``--dtype float32`` (default) then computes in float32, and the library's
:class:`hgjax.PrecisionWarning` about that is silenced because it is the requested
behaviour; ``--dtype float64`` turns on JAX's x64 mode for the run.

JAX's persistent compilation cache is on, in ``$HGJAX_CACHE_DIR`` (empty: off), else
``$XDG_CACHE_HOME/hgjax/jax``, else ``~/.cache/hgjax/jax``, so a second run skips the
compilation of the first. Within one run, files of different sizes share the compiled
kernels (the library streams fixed-size chunks).

Exit codes: 0 success; 1 failure while computing or writing (with ``--keep-going``: some
inputs failed, the others were written); 2 invalid arguments or input, detected before any
computation (bad option, ratio, count, seed or parameter, unreadable input, an attribute
the output format cannot hold, unwritable output, too many samples for the memory); 130
interrupted (Ctrl-C), 143 terminated (SIGTERM), with no partial file left. Messages go to
stderr, tables to stdout; user errors never print a Python traceback. A run's progress goes to
stderr too (:mod:`hgjax._progress`): its labelled stages with the points done, rate and time
left, as plain lines where stderr is not a terminal; ``-q`` leaves only warnings and errors,
``--no-progress`` the summaries, ``-v`` adds each stage's seconds.

One room: :mod:`hgjax.cli._main` holds the parser, the run's JAX settings and the dispatch
(:func:`main`); the commands live in modules of their own, none of which imports NumPy or JAX at module level:
:mod:`hgjax.cli._common` (errors, inputs and outputs, one method on one cloud),
:mod:`hgjax.cli._batch` (``resample`` and ``score`` file by file), :mod:`hgjax.cli._survey`
(``resample`` of a survey in tiles), :mod:`hgjax.cli._compare` (``compare`` and ``demo``) and
:mod:`hgjax.cli._signals` (SIGINT, SIGTERM and the console script's exit).
"""

import lazy_loader

# Loaded on first use, so that ``import hgjax.cli`` imports nothing but this file and the console
# script installs its signal handlers (:func:`exit_on_signals`) before the parser is imported.
_EXPORTS = {
    "_main": ["COMMANDS", "build_parser", "main"],
    "_signals": ["exit_on_signals"],
}
__getattr__, __dir__, __all__ = lazy_loader.attach(__name__, submod_attrs=_EXPORTS)
