"""Progress bars of long runs (tqdm): drawn on a terminal, quiet otherwise (logs, pipes, tests).

Each bar counts the work that is really done: design rounds, simulated steps, control steps. A
control run's length is not known in advance (it stops when every target has converged), so its
bar counts steps without a total and names the targets done; the design bar's ETA comes from the
rounds already finished.
"""

from __future__ import annotations

import sys

__all__ = ["Bar", "DesignProgress", "ControlProgress"]


def _on_terminal(stream) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):
        return False


class Bar:
    """A tqdm bar on ``stream`` (stderr), disabled when it is not a terminal; a context manager."""

    def __init__(self, total=None, desc: str = "", unit: str = "it", stream=None):
        from tqdm import tqdm

        stream = stream if stream is not None else sys.stderr
        self.tqdm = tqdm(total=total, desc=desc, unit=unit, file=stream, disable=not _on_terminal(stream),
                         dynamic_ncols=True, leave=True, mininterval=0.2)

    def advance(self, n: int = 1) -> None:
        """Count ``n`` more units of finished work."""
        self.tqdm.update(n)

    def to(self, done: int) -> None:
        """Set the count of finished work to ``done``."""
        self.tqdm.update(max(0, done - self.tqdm.n))

    def note(self, text: str) -> None:
        """Show what is being done now beside the bar (drawn at most every 0.2 s)."""
        self.tqdm.set_postfix_str(text, refresh=False)
        self.tqdm.update(0)

    def close(self) -> None:
        self.tqdm.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class DesignProgress(Bar):
    """A design run: one unit per finished round (its ETA from the rounds so far), the round's
    control step and targets done beside it."""

    def __init__(self, rounds: int, stream=None):
        super().__init__(total=rounds, desc="design", unit="round", stream=stream)

    def update(self, i, n_rounds, step, max_steps, done, worlds) -> None:
        """The designer's ``progress`` callback."""
        self.note(f"round {i}/{n_rounds}: control step {step}, {done}/{worlds} targets done")

    def wrap_round(self, on_round):
        """``on_round`` that also counts the finished round."""
        def counted(i, design, results):
            on_round(i, design, results)
            self.to(i + 1)
        return counted


class ControlProgress(Bar):
    """A control run: control steps counted as they run (no total: a run ends when every target
    has converged), the targets done beside them."""

    def __init__(self, stream=None, desc: str = "control"):
        super().__init__(total=None, desc=desc, unit="step", stream=stream)

    def update(self, step, max_steps, done, worlds) -> None:
        """The controller's ``progress`` callback."""
        self.to(step)
        self.note(f"{done}/{worlds} targets done")
