"""Ctrl-C held over the moments where an interrupt does harm, and delivered as soon as they end.

- USD's modules loading (``held_interrupts`` in ``io.usd_common.load_pxr``): USD catches a
  ``KeyboardInterrupt`` raised inside its module loading, prints pages of errors, is left half
  loaded and goes on as if nothing happened.
- The start of the ``warp-shape`` command (``hold_for_the_command``, called first thing by the
  package): importing the package and Warp takes a second or more, during which Ctrl-C would end
  the process with a traceback from the middle of an import. The command's ``main`` ends the hold
  (``release_the_command``) once its own handling is in place, so the press ends it in one line.

Only the main thread installs handlers; importing warp_shape in any other program installs none.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from contextlib import contextmanager

__all__ = ["held_interrupts", "hold_for_the_command", "release_the_command", "COMMAND"]

COMMAND = "warp-shape"  # the console script's name
_START: dict = {}  # the start-up hold: {"previous": handler, "pressed": [signals]}


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


@contextmanager
def held_interrupts():
    """Ctrl-C inside the block waits for its end, then goes to the handler in place before (by default
    a ``KeyboardInterrupt`` there)."""
    if not _main_thread():
        yield
        return
    pressed: list = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: pressed.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if pressed:
        signal.raise_signal(signal.SIGINT)


def hold_for_the_command() -> None:
    """In the ``warp-shape`` process only (its console script), hold Ctrl-C from now until
    ``release_the_command``."""
    name = os.path.basename(sys.argv[0]) if sys.argv and sys.argv[0] else ""
    if not name.startswith(COMMAND) or _START or not _main_thread():
        return
    pressed: list = []
    _START.update(previous=signal.signal(signal.SIGINT, lambda signum, frame: pressed.append(signum)),
                  pressed=pressed)


def release_the_command():
    """End the start-up hold, called with the command's own handler in place: (the handler from before
    the hold, to restore when the command ends, or None where nothing held; whether Ctrl-C was pressed
    while it held)."""
    if not _START:
        return None, False
    return _START.pop("previous"), bool(_START.pop("pressed"))
