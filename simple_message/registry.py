"""Named values that users extend: one small registry type for every such table.

The project's extension points are tables by name: dialects (:mod:`.dialects`), the emulator's
profiles and interpolation policies (``robot_server``). Each is a :class:`Registry`: a ``dict``
from name to value (so reading it is plain dict use) with the rules of adding to it in one place:
a name already taken is refused unless replacing is asked for, an unknown name is an error that
lists the known ones, and a test can undo its changes with :meth:`Registry.scoped`.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Generic, TypeVar

__all__ = ["Registry"]

T = TypeVar("T")


class Registry(dict[str, T], Generic[T]):
    """Values of one ``kind`` by name (see the module doc)."""

    def __init__(self, kind: str, error: type[Exception] = ValueError) -> None:
        super().__init__()
        #: what the values are, for messages ("dialect", "interpolation policy")
        self.kind = kind
        #: the error an unknown name raises (its message lists the known names)
        self.error = error

    def add(self, name: str, value: T, *, replace: bool = False) -> T:
        """Register ``value`` as ``name`` and return it. :class:`ValueError` if another value has
        that name, unless ``replace``; adding the same value again does nothing."""
        old = self.get(name)
        if old is not None and old is not value and not replace:
            raise ValueError(f"a {self.kind} named {name!r} is already registered; pass replace=True to replace it")
        self[name] = value
        return value

    def named(self, name: str) -> T:
        """The value called ``name``; :attr:`error` naming the known ones otherwise."""
        try:
            return self[name]
        except KeyError:
            raise self.error(f"unknown {self.kind} {name!r} (known: {', '.join(sorted(self))})") from None

    def remove(self, name: str) -> T | None:
        """Forget ``name``; its value, or None if there was none."""
        return self.pop(name, None)

    @contextmanager
    def scoped(self) -> Iterator[Registry[T]]:
        """Undo every change made inside the block on leaving it (the same object, as entered)."""
        saved = dict(self)
        try:
            yield self
        finally:
            self.clear()
            self.update(saved)
