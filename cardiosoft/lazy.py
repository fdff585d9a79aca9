"""Public names imported on first use (PEP 562), so that importing a package costs only what
its caller uses: ``import cardiosoft`` imports no JAX, a scene's modules no svZeroDSolver
reader (issue #41)."""

from __future__ import annotations

import importlib

__all__ = ["on_first_use"]


def on_first_use(namespace: dict, public: dict[str, str], renamed: dict[str, str] | None = None):
    """``(__getattr__, __dir__)`` of the package whose globals are ``namespace``: each name of
    ``public`` (name -> the module that defines it; ``renamed``: name -> its name there) is
    imported when first asked for and then kept, a submodule likewise; anything else is an
    ``AttributeError``."""
    package = namespace["__name__"]
    renamed = renamed or {}

    def __getattr__(name: str):
        if name in public:
            value = getattr(importlib.import_module(public[name]), renamed.get(name, name))
        else:
            try:
                value = importlib.import_module(f"{package}.{name}")
            except ModuleNotFoundError as e:
                if e.name != f"{package}.{name}":  # the submodule exists; what it imports not
                    raise
                raise AttributeError(f"module {package!r} has no attribute {name!r}") from None
        namespace[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted({*namespace, *namespace.get("__all__", ())})

    return __getattr__, __dir__
