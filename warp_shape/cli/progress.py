"""Progress of long runs: a tqdm bar on a terminal; elsewhere (a log, a pipe) a plain line when a run
enters a new phase and at least once a minute (``LOG_EVERY_S``), so a log shows the run working.

Each bar counts the work that is really done: design phases, simulated steps, control steps. A
control run's length is not known in advance (it stops when every target has converged), so its
bar counts steps without a total and names the targets done; the design bar counts its phases by
the time they take (the final round's and the refinement's model-based control dominate) and its
ETA comes from the construction rounds already finished.
"""

from __future__ import annotations

import re
import shutil
import sys
import threading
import time

__all__ = ["Bar", "DesignProgress", "ControlProgress", "LOG_EVERY_S", "without_progress"]


def _on_terminal(stream) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):
        return False


def without_progress(text: str) -> str:
    """``text`` (a run's stderr) less the progress lines ``Bar`` writes off a terminal ("<what>: ... [m:ss]")."""
    return "".join(ln for ln in text.splitlines(keepends=True) if not _PROGRESS_LINE.match(ln))


_PROGRESS_LINE = re.compile(r"^[a-z ]+: .* \[\d+:\d\d\]\n?$")  # "design: ... [0:35]"

#: off a terminal, a progress line at least this often (seconds) while news comes, and at each new phase
LOG_EVERY_S = 60.0


class Bar:
    """A tqdm bar on ``stream`` (stderr) on a terminal, its clock redrawn every second, so a long step
    without news still shows time passing; elsewhere a line per phase (``log_key``) and per minute
    (``LOG_EVERY_S``) of what runs now. A context manager."""

    def __init__(self, total=None, desc: str = "", unit: str = "it", stream=None, smoothing: float = 0.3,
                 bar_format: str | None = None):
        from tqdm import tqdm  # here, not at the top: its ~20 ms stay out of start-up (warp-shape --help)

        stream = stream if stream is not None else sys.stderr
        size = shutil.get_terminal_size((100, 24))  # a terminal that reports no size gets 100 x 24
        self.tqdm = tqdm(total=total, desc=desc, unit=unit, file=stream, disable=not _on_terminal(stream),
                         ncols=size.columns, nrows=size.lines, leave=True, mininterval=0.2,
                         smoothing=smoothing, bar_format=bar_format)
        self._drawn = 0.0
        self._text = ""
        self._stream, self._desc = stream, desc
        self._t0, self._logged_at = time.monotonic(), float("-inf")  # the first note is a line
        self._logged_key = None
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

    def log_key(self):
        """What a new progress line is written for off a terminal (besides each minute): nothing here."""
        return None

    def _log(self, text: str) -> None:
        """Off a terminal: ``text`` as a line on the stream where the phase changed or a minute passed."""
        now, key = time.monotonic(), self.log_key()
        if key == self._logged_key and now - self._logged_at < LOG_EVERY_S:
            return
        self._logged_at, self._logged_key = now, key
        print(f"{self._desc}: {self.compose(text)} [{_clock(now - self._t0)}]", file=self._stream, flush=True)

    def note(self, text: str) -> None:
        """Show what is being done now beside the bar (drawn at most every 0.2 s); off a terminal, a line
        now and then (``_log``)."""
        if self.tqdm.disable:
            self._text = text
            self._log(text)
            return
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


#: How long each phase of a design takes, in construction rounds (one construction round: every
#: target controlled by the paper's law, then the next placement), measured in two `make demo` runs
#: (oval + heart, 4 IPAMs) on the busy 2-core machine: rounds 0-3 about 4.3 s each; the final round
#: with the model-based refinement of its control 8.5 to 8.7 times as long; the simulated
#: placement's refinement (one batch of 9 worlds, one round) 12.5 to 18 times; the outputs (molds,
#: USD, figures) about 2.5 times.
FINAL_ROUND_WEIGHT = 9.0
REFINE_WEIGHT = 15.0
OUTPUTS_WEIGHT = 2.5
#: what the bar says before the first control step: Warp loads its kernels (compiles them on a first run)
STARTING = "compiling kernels (first run only; cached after)"


def _clock(seconds: float) -> str:
    return f"{int(seconds // 60)}:{int(seconds % 60):02d}"


class DesignProgress(Bar):
    """A design run, as phases weighted by the time they take (``FINAL_ROUND_WEIGHT`` etc.): the
    construction rounds, the final round (its model-based refinement included), the simulated
    placement's refinement rounds and the writing of the outputs. The bar moves within a phase as
    its estimate runs (never past it), the text beside it says what runs now and for how long; the
    ETA comes from the construction rounds' measured pace and is "?" while unknown or overrun."""

    def __init__(self, rounds: int, n_targets: int = 1, refine_last: bool = True, stream=None,
                 refine_rounds: bool = False, outputs: bool = False):
        self.n_rounds = max(1, int(rounds)) - 1  # rounds 0 .. n_rounds, the last being the final round
        self.weights = [1.0] * self.n_rounds + [FINAL_ROUND_WEIGHT if refine_last else 1.0] \
            + ([REFINE_WEIGHT] if refine_rounds else []) + ([OUTPUTS_WEIGHT] if outputs else [])
        self.starts = [sum(self.weights[:k]) for k in range(len(self.weights))]
        super().__init__(total=sum(self.weights), desc="design", unit="round", stream=stream,
                         bar_format="{desc}: {percentage:3.0f}%|{bar}| [{elapsed}{postfix}]")
        self.n_targets = max(1, int(n_targets))
        self.refine_last = refine_last
        self.phase = 0
        self._start = None  # the first control step (after the kernels are loaded)
        self._phase_start = time.monotonic()
        self._pace = None  # seconds per construction round, once one has finished
        self.note(STARTING)

    def log_key(self):
        return self.phase, self._start is None  # each phase, and the first step after the kernels load

    def _enter(self, phase: int) -> None:
        """Phase ``phase`` starts (the phases before it are done)."""
        phase = min(phase, len(self.weights) - 1)
        if phase <= self.phase and self.tqdm.n > 0:
            return
        now = time.monotonic()
        if self._start is None:
            self._start = now
        if self.phase < self.n_rounds and self.phase < phase <= self.n_rounds:
            self._pace = max(1e-3, (now - self._start) / phase)
        self.phase, self._phase_start = phase, now
        Bar.to(self, self.starts[phase])

    def _creep(self) -> None:
        """Move the bar within the current phase as its estimate runs (up to 95 % of the phase)."""
        if self._pace is None:
            return
        w = self.weights[self.phase]
        frac = min(0.95, (time.monotonic() - self._phase_start) / (self._pace * w))
        target = self.starts[self.phase] + frac * w
        if target > self.tqdm.n:
            self.tqdm.update(target - self.tqdm.n)

    def eta(self) -> str:
        """Time left: the construction rounds' pace times the weight of the phases left, less the time
        the current phase has run; "?" before the first round is done; once the current phase has run
        past its estimate, "> m:ss" (at least the phases after it), or "?" in the last phase."""
        if self.tqdm.n >= self.tqdm.total:
            return "0:00"
        if self._pace is None:
            return "?"
        ran = time.monotonic() - self._phase_start
        now = self._pace * self.weights[self.phase]
        after = self._pace * (self.tqdm.total - self.starts[self.phase]) - now
        if ran <= now:
            return _clock(after + now - ran)
        return f"> {_clock(after)}" if after >= 1.0 else "?"  # this phase overran its estimate

    def compose(self, text: str) -> str:
        if text == "done":
            return text
        self._creep()
        ran = time.monotonic() - self._phase_start
        return f"ETA {self.eta()}, {self.phase + 1}/{len(self.weights)} {text}" + (f" ({ran:.0f} s)" if ran >= 5 else "")

    def update(self, i, n_rounds, step, max_steps, done, worlds) -> None:
        """The designer's ``progress`` callback."""
        refining = worlds > self.n_targets and i >= n_rounds
        self._enter(i + (1 if refining and len(self.weights) > self.n_rounds + 1 else 0))
        if refining:
            text = f"refinement, {worlds} worlds: " + (f"step {step}" if done < worlds else "model-based")
        elif worlds > self.n_targets:
            text = f"round {i}/{n_rounds}: {worlds // self.n_targets} candidate sets, step {step}"
        elif self.refine_last and i == n_rounds and done == worlds:
            text = f"final round: model-based control"
        else:
            text = f"round {i}/{n_rounds}: step {step}, {done}/{worlds} done"
        self.note(text)

    def writing_outputs(self) -> None:
        """The outputs are being written (the last phase)."""
        self._enter(len(self.weights) - 1)
        self.note("writing the outputs")

    def wrap_round(self, on_round):
        """``on_round`` that also counts the last round as done."""
        def counted(i, design, results):
            on_round(i, design, results)
            if i >= self.n_rounds and len(self.weights) > self.n_rounds + 1:
                self._enter(self.n_rounds + 1)
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
