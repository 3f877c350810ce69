"""Lazy public names for a package (PEP 562): a name's module is imported on first use, so
``import facegeo`` and building the command line's parser do not pay for torch, OpenCV, USD or
diffusers until a name that needs them is touched. Every package of facegeo uses this one helper.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from importlib import import_module
from typing import Any

__all__ = ["lazy_exports"]


def lazy_exports(package: str, exports: dict[str, str]) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """``(__getattr__, __dir__)`` for the package named ``package``.

    Args:
        package: the package's ``__name__`` (it must be in ``sys.modules``, i.e. call this from
            its ``__init__``).
        exports: public name -> the module that defines it: absolute (``"facegeo.uv.raster"``)
            or relative to ``package`` (``".backend"``).
    Returns:
        The two module-level hooks: ``__getattr__`` imports a name's module on first access and
        caches the value in the package's namespace (AttributeError for unknown names);
        ``__dir__`` lists the namespace and the lazy names.
    """
    namespace = sys.modules[package].__dict__

    def __getattr__(name: str) -> Any:
        if name not in exports:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(import_module(exports[name], package), name)
        namespace[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted(set(namespace) | set(exports))

    return __getattr__, __dir__
