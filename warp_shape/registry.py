"""Registries of strategies: control methods, control laws, placements, picked by name.

A registry maps a name to an entry that carries ``name`` and a one-line ``summary``. The settings
that pick a strategy are checked against it, and the command line takes its choices and help text
from it, so a strategy registered from outside the package (``register``, or a module named in
``WARP_SHAPE_PLUGINS``) is usable everywhere a built-in one is.
"""

from __future__ import annotations

import difflib
import importlib
import os

from .errors import DesignError

__all__ = ["Registry", "load_plugins", "PLUGINS_VARIABLE"]

#: environment variable: comma-separated modules imported before the command line is parsed, each
#: registering its strategies (e.g. ``WARP_SHAPE_PLUGINS=my_lab.laws``)
PLUGINS_VARIABLE = "WARP_SHAPE_PLUGINS"


class Registry:
    """Entries by name, in registration order. ``kind`` names them in errors ("control method")."""

    def __init__(self, kind: str):
        self.kind = kind
        self._entries: dict = {}

    def register(self, entry, *, replace: bool = False):
        """Add ``entry`` (it has ``name`` and ``summary``) and return it; a name taken already is an
        error unless ``replace``."""
        name = getattr(entry, "name", None)
        if not isinstance(name, str) or not name.isidentifier():
            raise DesignError(f"a {self.kind} needs a name that is an identifier, got {name!r}")
        if not isinstance(getattr(entry, "summary", None), str):
            raise DesignError(f"{self.kind} {name!r} needs a one-line summary (a str attribute 'summary')")
        if name in self._entries and not replace and self._entries[name] is not entry:
            raise DesignError(f"{self.kind} {name!r} is registered already; pass replace=True to replace it")
        self._entries[name] = entry
        return entry

    def unregister(self, name: str) -> None:
        """Remove ``name`` (a strategy registered for a while, e.g. in a test)."""
        self._entries.pop(name, None)

    def __contains__(self, name) -> bool:
        return name in self._entries

    def __iter__(self):
        return iter(self._entries)

    def __len__(self) -> int:
        return len(self._entries)

    def get(self, name):
        """The entry called ``name``; an unknown name is an error listing the choices and the closest."""
        try:
            return self._entries[name]
        except (KeyError, TypeError):
            close = difflib.get_close_matches(str(name), list(self._entries), n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise DesignError(f"unknown {self.kind} {name!r}{hint}; choose one of {list(self._entries)}") from None

    __getitem__ = get

    def check(self, name, setting: str) -> None:
        """Raise if ``name`` (the value of ``setting``) is not registered."""
        try:
            self.get(name)
        except DesignError as exc:
            raise DesignError(f"{setting}: {exc}") from None

    def help(self) -> str:
        """'name: summary; ...' for a command-line help text."""
        return "; ".join(f"{n}: {e.summary}" for n, e in self._entries.items())


def load_plugins(value: str | None = None) -> list[str]:
    """Import the modules named in ``value`` (default: the ``WARP_SHAPE_PLUGINS`` variable); a module
    that cannot be imported is an error naming it. Returns the names imported."""
    value = os.environ.get(PLUGINS_VARIABLE, "") if value is None else value
    names = [n.strip() for n in value.split(",") if n.strip()]
    for name in names:
        try:
            importlib.import_module(name)
        except ImportError as exc:
            raise DesignError(f"{PLUGINS_VARIABLE} names module {name!r}, which cannot be imported: {exc}") from None
        except Exception as exc:  # the module itself fails as it runs: a syntax error, any error of its own
            raise DesignError(f"{PLUGINS_VARIABLE} names module {name!r}, which failed as it was imported "
                              f"({type(exc).__name__}: {exc}); fix the module, or leave it out of "
                              f"{PLUGINS_VARIABLE}") from None
    return names
