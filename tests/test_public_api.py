"""Every public function and class is documented (Args, Returns, Examples) and takes its
optional arguments by keyword only."""

import inspect
import types

import pytest

import hgjax
import hgjax.plot  # noqa: F401  (not imported by hgjax itself: matplotlib is optional)

NAMESPACES = {"hgjax": hgjax, "hgjax.scores": hgjax.scores, "hgjax.eval": hgjax.eval, "hgjax.io": hgjax.io,
              "hgjax.plot": hgjax.plot}

# Documented exceptions to "optional arguments are keyword-only", as (qualified name, argument).
POSITIONAL_DEFAULTS = {
    # Per-neighbourhood kernels receive their traced arguments positionally from
    # hgjax.scores._common.map_neighbourhoods; HKF's spectrum (v, t) is optional there.
    ("hgjax.scores.hkf_neighbourhood", "v"),
    ("hgjax.scores.hkf_neighbourhood", "t"),
}


def _public():
    for prefix, module in NAMESPACES.items():
        for name in getattr(module, "__all__", []):
            obj = getattr(module, name)
            if isinstance(obj, types.ModuleType) or not callable(obj):
                continue
            yield pytest.param(f"{prefix}.{name}", obj, id=f"{prefix}.{name}")


PUBLIC = list(_public())


@pytest.mark.parametrize("qualname, obj", PUBLIC)
def test_docstring_sections(qualname, obj):
    doc = inspect.getdoc(obj) or ""
    assert doc.strip(), f"{qualname} has no docstring"
    if inspect.isclass(obj) and issubclass(obj, BaseException):
        return  # exceptions and warnings: a docstring saying when they are raised is enough
    is_class = inspect.isclass(obj)
    params = [] if is_class and not _has_init_args(obj) else list(_signature(obj).parameters)
    if params or is_class:
        assert "Args:" in doc or "Attributes:" in doc, f"{qualname}: no Args/Attributes section"
    if not is_class:
        assert "Returns:" in doc or "Yields:" in doc, f"{qualname}: no Returns section"
    assert "Examples:" in doc and ">>>" in doc, f"{qualname}: no Examples section with a doctest"


@pytest.mark.parametrize("qualname, obj", PUBLIC)
def test_optional_arguments_are_keyword_only(qualname, obj):
    if inspect.isclass(obj):
        return  # dataclass / NamedTuple fields may be positional
    for param in _signature(obj).parameters.values():
        if param.default is not inspect.Parameter.empty and (qualname, param.name) not in POSITIONAL_DEFAULTS:
            assert param.kind is inspect.Parameter.KEYWORD_ONLY, (
                f"{qualname}: optional argument {param.name!r} must be keyword-only")


def _signature(obj):
    try:
        return inspect.signature(obj)
    except (TypeError, ValueError):
        return inspect.Signature()


def _has_init_args(cls):
    return len(_signature(cls).parameters) > 0


def test_every_namespace_has_an_all():
    for prefix, module in NAMESPACES.items():
        assert isinstance(module.__all__, list) and module.__all__, prefix
        for name in module.__all__:
            assert hasattr(module, name), f"{prefix}.__all__ names missing {name!r}"
