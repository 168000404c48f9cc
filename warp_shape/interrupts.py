"""Ctrl-C held over the moments where an interrupt does harm, and delivered as soon as they end.

- USD's modules loading (``held_interrupts`` in ``io.usd_common.load_pxr``): USD catches a
  ``KeyboardInterrupt`` raised inside its module loading, prints pages of errors, is left half
  loaded and goes on as if nothing happened.
- The start of the ``warp-shape`` command (``hold_for_the_command``, called first thing by the
  package): importing the package and Warp takes a second or more, during which Ctrl-C would end
  the process with a traceback from the middle of an import. The command's ``main`` ends the hold
  (``release_the_command``) once its own handling is in place, so the press ends it in one line.

The hold starts as early as a package can: this module imports only what the interpreter and its
``site`` start-up have loaded already (``signal`` aside, which is small), so nothing but Python's
own start-up precedes it (docs/reliability.md measures what is left). Only the main thread installs
handlers (``signal.signal`` refuses elsewhere); importing warp_shape in any other program installs none.
"""

from __future__ import annotations

import os
import signal
import sys

__all__ = ["held_interrupts", "hold_for_the_command", "release_the_command", "COMMAND"]

COMMAND = "warp-shape"  # the console script's name
_START: dict = {}  # the start-up hold: {"previous": handler, "pressed": [signals]}
_OFF_MAIN_THREAD = object()  # what ``_catch`` returns where Python takes no signal handler


def _catch(pressed: list):
    """Note Ctrl-C presses in ``pressed`` from now: the handler in place before, or ``_OFF_MAIN_THREAD``."""
    try:
        return signal.signal(signal.SIGINT, lambda signum, frame: pressed.append(signum))
    except ValueError:  # not the main thread
        return _OFF_MAIN_THREAD


class _Held:
    """The context of ``held_interrupts``."""

    def __enter__(self):
        self.pressed: list = []
        self.previous = _catch(self.pressed)
        return self

    def __exit__(self, exc_type, exc, tb):
        if self.previous is _OFF_MAIN_THREAD:
            return False
        signal.signal(signal.SIGINT, self.previous)
        if self.pressed and exc_type is None:
            signal.raise_signal(signal.SIGINT)
        return False


def held_interrupts() -> _Held:
    """A ``with`` block in which Ctrl-C waits for the block's end, then goes to the handler in place
    before (by default a ``KeyboardInterrupt`` there); off the main thread, a block like any other."""
    return _Held()


def hold_for_the_command() -> None:
    """In the ``warp-shape`` process only (its console script), hold Ctrl-C from now until
    ``release_the_command``."""
    name = os.path.basename(sys.argv[0]) if sys.argv and sys.argv[0] else ""
    if not name.startswith(COMMAND) or _START:
        return
    pressed: list = []
    previous = _catch(pressed)
    if previous is not _OFF_MAIN_THREAD:
        _START.update(previous=previous, pressed=pressed)


def release_the_command():
    """End the start-up hold, called with the command's own handler in place: (the handler from before
    the hold, to restore when the command ends, or None where nothing held; whether Ctrl-C was pressed
    while it held)."""
    if not _START:
        return None, False
    return _START.pop("previous"), bool(_START.pop("pressed"))
