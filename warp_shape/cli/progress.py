"""Progress bars of long runs (tqdm): drawn on a terminal, quiet otherwise (logs, pipes, tests).

Each bar counts the work that is really done: design rounds, simulated steps, control steps. A
control run's length is not known in advance (it stops when every target has converged), so its
bar counts steps without a total and names the targets done; the design bar's ETA comes from the
rounds already finished (tqdm's moving average).
"""

from __future__ import annotations

import shutil
import sys
import threading
import time

__all__ = ["Bar", "DesignProgress", "ControlProgress"]


def _on_terminal(stream) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):
        return False


class Bar:
    """A tqdm bar on ``stream`` (stderr), disabled when it is not a terminal; a context manager. Its
    clock is redrawn every second, so a long step without news still shows time passing."""

    def __init__(self, total=None, desc: str = "", unit: str = "it", stream=None, smoothing: float = 0.3):
        from tqdm import tqdm  # here, not at the top: its ~20 ms stay out of start-up (warp-shape --help)

        stream = stream if stream is not None else sys.stderr
        size = shutil.get_terminal_size((100, 24))  # a terminal that reports no size gets 100 x 24
        self.tqdm = tqdm(total=total, desc=desc, unit=unit, file=stream, disable=not _on_terminal(stream),
                         ncols=size.columns, nrows=size.lines, leave=True, mininterval=0.2,
                         smoothing=smoothing)
        self._drawn = 0.0
        self._text = ""
        self._stop = threading.Event()
        if not self.tqdm.disable:
            threading.Thread(target=self._tick, daemon=True).start()

    def _tick(self) -> None:
        while not self._stop.wait(1.0):
            self.tqdm.set_postfix_str(self.compose(self._text), refresh=False)
            self.tqdm.refresh()

    def compose(self, text: str) -> str:
        """The text beside the bar for ``text``, what runs now."""
        return text

    def to(self, done: int) -> None:
        """Set the count of finished work to ``done`` (never back)."""
        if done > self.tqdm.n:
            self.tqdm.update(done - self.tqdm.n)

    def note(self, text: str) -> None:
        """Show what is being done now beside the bar (drawn at most every 0.2 s)."""
        self._text = text
        self.tqdm.set_postfix_str(self.compose(text), refresh=False)
        now = time.monotonic()
        if now - self._drawn >= 0.2:
            self._drawn = now
            self.tqdm.refresh()

    def close(self) -> None:
        self._stop.set()
        self.tqdm.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        if exc[0] is None and self.tqdm.total is not None:
            self.to(self.tqdm.total)  # a run that ends early (nothing left to gain) is complete
            self._text = "done"
            self.tqdm.set_postfix_str("done", refresh=False)
        self.close()


#: the last design round (final control plus its model-based refinement) takes about two placement
#: rounds' time on the default problem (rounds 0-3: 4-7 s each; the last: 11 s)
FINAL_ROUND_WEIGHT = 2.0


class DesignProgress(Bar):
    """A design run: round i counts as done when round i + 1 starts (its control run and the
    placement after it, the work of every round but the last) or, for the last, when it is
    recorded; what runs now beside the bar: the round's control run, the candidate sets tried for
    the next actuator set, the model-based refinement of the final control."""

    def __init__(self, rounds: int, n_targets: int = 1, refine_last: bool = True, stream=None):
        super().__init__(total=rounds, desc="design", unit="round", stream=stream)
        self.tqdm.bar_format = "{desc}: {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} rounds [{elapsed}{postfix}]"
        self.n_targets = max(1, int(n_targets))
        self.refine_last = refine_last
        self._start = self._last_done = time.monotonic()

    def eta(self) -> str:
        """Time left: the mean time of the finished rounds for each round still to run (the last one,
        with the model-based refinement, as ``FINAL_ROUND_WEIGHT`` rounds), less the time the current
        one has run ("?" before the first round is done)."""
        n, total = self.tqdm.n, self.tqdm.total
        if n == 0 or n >= total:
            return "?" if n == 0 else "0:00"
        now = time.monotonic()
        rounds_left = total - n + (FINAL_ROUND_WEIGHT - 1.0 if self.refine_last else 0.0)
        left = max(0.0, rounds_left * (self._last_done - self._start) / n - (now - self._last_done))
        return f"{int(left // 60)}:{int(left % 60):02d}"

    def to(self, done: int) -> None:
        if done > self.tqdm.n:
            self._last_done = time.monotonic()
        super().to(done)

    def compose(self, text: str) -> str:
        return text if text == "done" else f"ETA {self.eta()}, {text}"

    def update(self, i, n_rounds, step, max_steps, done, worlds) -> None:
        """The designer's ``progress`` callback."""
        self.to(i)
        if worlds > self.n_targets and i >= n_rounds:
            text = f"round {i}/{n_rounds}: refining, {worlds} worlds, step {step}"
        elif worlds > self.n_targets:
            text = f"round {i}/{n_rounds}: {worlds // self.n_targets} candidate sets, step {step}"
        elif self.refine_last and i == n_rounds and done == worlds:
            text = f"round {i}/{n_rounds}: refining the final control"
        else:
            text = f"round {i}/{n_rounds}: step {step}, {done}/{worlds} targets done"
        self.note(text)

    def wrap_round(self, on_round):
        """``on_round`` that also counts the last round as done."""
        def counted(i, design, results):
            on_round(i, design, results)
            if i + 1 >= self.tqdm.total:
                self.to(i + 1)
        return counted


class ControlProgress(Bar):
    """A control run: control steps counted as they run (no total: a run ends when every target
    has converged), the targets done beside them, then the model-based refinement (``refine``)."""

    def __init__(self, stream=None, desc: str = "control", refine: bool = False):
        super().__init__(total=None, desc=desc, unit=" steps", stream=stream)
        self.refine = refine

    def update(self, step, max_steps, done, worlds) -> None:
        """The controller's ``progress`` callback."""
        self.to(step)
        if self.refine and done == worlds:
            self.note(f"{done}/{worlds} targets done; model-based refinement (no step count)")
        else:
            self.note(f"{done}/{worlds} targets done")
