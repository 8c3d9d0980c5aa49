"""The method registry: :data:`METHODS`, lookup by name, and the split of parameters by stage.

Each method module declares its own entry (:class:`hgjax.Method` or :class:`hgjax.Sampler`,
:mod:`hgjax._method`); this module only collects them, under the names :mod:`hgjax._names` lists
(the command line reads those without importing the method modules).
"""

from __future__ import annotations

from hgjax import _names, _validate, samplers
from hgjax._method import Method, Sampler
from hgjax.scores import ea, gfr, hkc, hkf, lhf, mss, pca_ac

__all__ = ["DEFAULT", "METHODS", "Method", "Sampler"]


def _by_name(*entries: Method | Sampler) -> dict[str, Method | Sampler]:
    """{name: entry} of ``entries``; RuntimeError unless their names are those :mod:`hgjax._names` lists."""
    found = {m.name: m for m in entries}
    declared = (tuple(sorted(n for n, m in found.items() if isinstance(m, Method))),
                tuple(sorted(n for n, m in found.items() if isinstance(m, Sampler))))
    if declared != (_names.SCORING, _names.SAMPLERS):
        raise RuntimeError(f"the method modules declare scoring methods {declared[0]} and samplers {declared[1]};"
                           f" hgjax._names lists {_names.SCORING} and {_names.SAMPLERS}")
    return found


METHODS: dict[str, Method | Sampler] = _by_name(
    hkc.METHOD, hkf.METHOD, lhf.METHOD, gfr.METHOD, ea.METHOD, pca_ac.METHOD, mss.METHOD, *samplers.SAMPLERS)
DEFAULT = _names.DEFAULT
"""The method of :func:`hgjax.resample`, :func:`hgjax.tiles.resample` and the command line when none is named."""


def entry(method: str) -> Method | Sampler:
    """The registry entry of ``method``; an unknown name raises ValueError listing the known ones."""
    return METHODS[_validate.check_choice(method, "method", METHODS)]


def scoring(method: str) -> Method:
    """The :class:`Method` of ``method``; a sampler (no scores) raises ValueError listing the scoring methods."""
    found = entry(method)
    if not isinstance(found, Method):
        raise ValueError(f"method {method!r} is a sampler without scores; expected one of {list(_names.SCORING)}")
    return found


def defaults(found: Method | Sampler) -> dict:
    """{parameter: default} of the build, score and select stages of ``found``, as the signatures of its
    stage functions declare them; a parameter whose stages disagree is left out, and so is ``search``,
    whose default is the backend's (:func:`hgjax.engine.searched`), not the signature's. {} for a sampler.

    Examples:
      >>> defaults(METHODS["hkc"])["kernel_size"], "search" in defaults(METHODS["hkc"])
      (3, False)
    """
    import inspect

    if not isinstance(found, Method):
        return {}
    seen: dict = {}
    for stage, fn in (("build", found.build), ("score", found.score), ("select", found.select)):
        if fn is None:
            continue
        for name, parameter in inspect.signature(fn).parameters.items():
            if name in found.params[stage] and parameter.default is not inspect.Parameter.empty:
                seen.setdefault(name, []).append(parameter.default)
    return {name: values[0] for name, values in seen.items()
            if name != "search" and all(v == values[0] for v in values)}


def check_known(found: Method | Sampler, params: dict) -> None:
    """Raise TypeError naming the parameters of ``params`` that no stage of ``found`` takes."""
    unknown = set(params) - found.accepted
    if unknown:
        raise TypeError(f"method {found.name!r} got unexpected parameter(s) {sorted(unknown)};"
                        f" it accepts {sorted(found.accepted)}")


def split(found: Method, stage: str, params: dict) -> dict:
    """The parameters of ``params`` that ``stage`` accepts; unknown names raise."""
    check_known(found, params)
    return {k: v for k, v in params.items() if k in found.params[stage]}
