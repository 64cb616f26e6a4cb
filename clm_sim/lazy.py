"""Names of a package resolved on first use (PEP 562): importing the package loads none of the
modules that define them, so a process pays for numpy, scipy or torch only when it uses a name
that needs them."""

from __future__ import annotations

import importlib
from collections.abc import Callable


def lazy_exports(package: str, exports: dict[str, str],
                 namespace: dict) -> tuple[Callable, Callable]:
    """``(__getattr__, __dir__)`` for ``package``, whose public names ``exports`` maps to the
    module that defines each; ``namespace`` is the package's ``globals()`` (a name resolved
    once is kept there, and its ``__all__`` is what ``dir`` lists)."""

    def __getattr__(name: str):
        if name in exports:
            value = getattr(importlib.import_module(exports[name]), name)
            namespace[name] = value
            return value
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def __dir__() -> list[str]:
        return sorted(namespace.get("__all__", exports))

    return __getattr__, __dir__
