"""A package root's public names, imported from their modules on first use.

A package ``__init__`` that imports every public name makes each of its modules cost the whole
package: ``import simple_message.messages`` would load asyncio, the endpoints and the capture
reader, ``import robot_server.model`` the emulator. With :class:`LazyExports` the root names where
each public name lives, and a name's module is imported when the name is first read
(``from simple_message import Client``, ``simple_message.Client``), once. The package's modules
are attributes of it on first use as well, as they were when the root imported them. The roots of
:mod:`simple_message`, :mod:`robot_server` and :mod:`robot_server.control` use it; each repeats
its names in an ``if TYPE_CHECKING:`` import, for mypy and editors, and ``tests/test_imports.py``
checks the two lists and ``__all__`` agree.
"""

from __future__ import annotations

import importlib
import importlib.util
from collections.abc import Iterable, Mapping
from typing import Any

__all__ = ["LazyExports"]


class LazyExports:
    """The public names of ``package`` by module: ``modules`` maps a module, relative to the
    package (``".endpoints"``), to the names it gives. ``namespace`` is the package's
    ``globals()``: a name read once is kept there, so that later reads are plain look-ups."""

    def __init__(self, package: str, namespace: dict[str, Any], modules: Mapping[str, Iterable[str]]) -> None:
        self.package = package
        self.namespace = namespace
        #: where each public name comes from
        self.origin: dict[str, str] = {}
        for module, names in modules.items():
            for name in names:
                if name in self.origin:
                    raise ValueError(f"{package}: {name} is exported by {self.origin[name]} and {module}")
                self.origin[name] = module

    def attribute(self, name: str) -> object:
        """The package's ``__getattr__``: the public ``name`` from its module, or the submodule
        ``name``; AttributeError for anything else."""
        module = self.origin.get(name)
        if module is not None:
            value = getattr(importlib.import_module(module, self.package), name)
            self.namespace[name] = value
            return value
        if not name.startswith("_") and importlib.util.find_spec(f"{self.package}.{name}") is not None:
            return importlib.import_module(f"{self.package}.{name}")
        raise AttributeError(f"module {self.package!r} has no attribute {name!r}")

    def names(self) -> list[str]:
        """The package's ``__dir__``: what it holds now and every public name."""
        return sorted(set(self.namespace) | set(self.origin))
