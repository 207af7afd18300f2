"""A package's flat API loaded on first use (PEP 562), so importing the package stays cheap."""

from __future__ import annotations

import sys
from importlib import import_module
from typing import Callable


def lazy_api(package: str, api: dict[str, tuple[str, str]]) -> tuple[Callable[[str], object], Callable[[], list[str]]]:
    """The module-level ``__getattr__`` and ``__dir__`` of `package` whose public name N is attribute
    ``api[N][1]`` of module ``api[N][0]``, imported when N is first used and then kept in the package's
    namespace (later look-ups are plain)."""

    def __getattr__(name: str) -> object:
        if name not in api:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        module, attribute = api[name]
        value = getattr(import_module(module), attribute)
        vars(sys.modules[package])[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted({*vars(sys.modules[package]), *api})

    return __getattr__, __dir__
