"""Every core: a batch of control jobs sharded over worker processes, each its own Warp CPU instance.

Warp's CPU backend runs a kernel as one serial loop on one thread, so one process uses one core.
``worker_pool(workers)`` opens a pool of worker processes for a run (a design run, a control run):
the workers start once, take one job at a time until the run ends, and are ended when it ends, on
an error and on Ctrl-C. Inside the block, ``control_many`` on the CPU runs each target of a batch
as its own job (``control_sharded``): one single-world control run per target, its result the one
``control_many(design, [target])`` gives in one process, bit for bit. docs/performance.md measures
the unit and says where the results differ from one batch of worlds.

``workers``: 0 means every core this process may use (its affinity mask; the ``WARP_SHAPE_WORKERS``
variable, where set, replaces that count), 1 the in-process path (no pool), N that many workers.
A pool of 1 is never started. The workers start with "spawn" (Warp's state is not fork-safe); they
do not import the caller's ``__main__`` (an unguarded script's body would run again in every
worker), so a job whose control method, law or actuator family is defined there runs in-process.
A worker's error is raised here as it was raised there (a warp_shape error keeps its type and
message); a worker that dies is a ``WorkerError``; either way the pool is ended first.
"""

from __future__ import annotations

import contextlib
import contextvars
import dataclasses
import importlib
import os
import pickle
import signal
import sys
import threading
import time
import traceback
from multiprocessing import get_context
from multiprocessing.connection import wait

import numpy as np
import warp as wp

from ..force_family import ACTUATOR_FAMILIES, FORCE_FAMILIES
from ..errors import DesignError, WarpShapeError
from ..mesh import TriMesh
from ..registry import load_plugins
from .problem import Problem
from .result import screened
from .control_settings import CONTROL_METHODS, LAWS

__all__ = ["WorkerPool", "WorkerError", "worker_pool", "current_pool", "run_jobs", "resolve_workers", "available_cores",
           "control_sharded", "run_method", "shard_modules", "WORKERS_VARIABLE", "MAX_WORKERS", "in_worker", "check_workers"]

#: environment variable: the worker count that ``workers = 0`` ("every core") means, e.g. 1 in a test suite
WORKERS_VARIABLE = "WARP_SHAPE_WORKERS"
MAX_WORKERS = 1024  # the most worker processes a run may ask for
PROGRESS_EVERY = 0.25  # s between a worker's progress messages
JOIN_TIMEOUT = 5.0  # s a worker is given to end before it is killed
IDLE_AFTER = 0.3  # s without a job after which a worker runs its idle tasks (``WorkerPool.when_idle``)
_SERIAL = "serial"  # the current pool of a run that asked for one process
_CURRENT = contextvars.ContextVar("warp_shape_worker_pool", default=None)
_STATE = {"worker": False}  # True in a worker process: jobs there never start pools of their own


class WorkerError(WarpShapeError, RuntimeError):
    """A worker process ended while it ran a job (killed, out of memory, a crash in native code)."""


def in_worker() -> bool:
    """Whether this process is a pool's worker."""
    return _STATE["worker"]


def available_cores() -> int:
    """The cores this process may run on (its affinity mask where the system has one)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def _workers_from_environment() -> int | None:
    value = os.environ.get(WORKERS_VARIABLE, "").strip()
    if not value:
        return None
    try:
        n = int(value)
    except ValueError:
        n = -1
    if n < 1:
        raise DesignError(f"{WORKERS_VARIABLE} must be a whole number >= 1 (worker processes), got {value!r}; "
                          f"unset it to use every core")
    return n


def check_workers(workers, owner: str) -> None:
    """Refuse a worker count that is not a whole number >= 0, naming ``owner`` (e.g. "DesignSettings.workers")."""
    if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 0:
        raise DesignError(f"{owner} must be a whole number >= 0 (worker processes; 0: every core, 1: one "
                          f"process), got {workers!r}")


def resolve_workers(workers: int = 0) -> int:
    """The worker processes ``workers`` asks for (module docstring); 1 inside a worker."""
    check_workers(workers, "workers")
    if _STATE["worker"]:
        return 1
    if workers == 0:
        return _workers_from_environment() or available_cores()
    return int(workers)


def current_pool():
    """The pool of the run in progress, or None (no run, or a run in one process)."""
    pool = _CURRENT.get()
    return pool if isinstance(pool, WorkerPool) else None


def run_jobs(fn, jobs: list) -> list:
    """``[fn(*job) for job in jobs]``: on the workers of the run in progress where they are running
    (``WorkerPool.run``, one job each), else in this process (no pool, a pool not started, one job)."""
    pool = current_pool()
    if pool is not None and pool.pids and len(jobs) > 1:
        return pool.run(fn, jobs)
    return [fn(*job) for job in jobs]


@contextlib.contextmanager
def worker_pool(workers: int = 0):
    """A run's pool of ``resolve_workers(workers)`` processes (None for one process), ended when the
    block ends. Inside a run that has one already (an outer ``worker_pool``), that one is used."""
    outer = _CURRENT.get()
    if outer is not None:
        yield current_pool()
        return
    n = resolve_workers(workers)
    pool = WorkerPool(n) if n > 1 else None
    token = _CURRENT.set(pool if pool is not None else _SERIAL)
    try:
        yield pool
    finally:
        _CURRENT.reset(token)
        if pool is not None:
            pool.close()


class _Worker:
    def __init__(self, process, conn):
        self.process, self.conn, self.job = process, conn, None


class WorkerPool:
    """``size`` worker processes, started on first use and kept until ``close`` (module docstring)."""

    def __init__(self, size: int):
        if size < 1:
            raise DesignError(f"a worker pool needs at least one worker, got {size}")
        self.size = int(size)
        self._workers: list[_Worker] = []
        self._idle: list = []  # ``when_idle`` tasks, sent to every worker
        self.job_seconds: list[list[float]] = []  # per ``run``: each job's CPU time in its worker, s

    @property
    def pids(self) -> list[int]:
        """The worker processes' ids (empty before the pool starts and after it ends)."""
        return [w.process.pid for w in self._workers]

    def start(self, jobs: int | None = None) -> "WorkerPool":
        """Start workers up to ``min(size, jobs)`` (default ``size``): a pool grows to its largest batch
        and no further. They load the package while the caller goes on. Ctrl-C is blocked while they
        start, so none of them inherits a handler; the caller gets the press afterwards."""
        want = self.size if jobs is None else max(1, min(self.size, int(jobs)))
        if len(self._workers) >= want:
            return self
        ctx = get_context("spawn")
        blocked = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            with _main_hidden():
                for _ in range(want - len(self._workers)):
                    mine, theirs = ctx.Pipe()
                    p = ctx.Process(target=_worker_main, args=(theirs,), name="warp-shape-worker", daemon=True)
                    p.start()
                    theirs.close()
                    self._workers.append(_Worker(p, mine))
                    for task in self._idle:
                        mine.send(("when_idle", task))
        except BaseException:
            self.close()
            raise
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, blocked)
        return self

    def when_idle(self, task) -> None:
        """Have every worker, now and started later, call ``task()`` (a module-level function, once) the
        first time it has waited ``IDLE_AFTER`` s for a job: work a later job needs (say, loading a
        library) done while the worker would wait. A task's failure is ignored."""
        self._idle.append(task)
        for w in self._workers:
            w.conn.send(("when_idle", task))

    def run(self, fn, jobs: list, *, modules=(), progress=None) -> list:
        """``[fn(*job, progress=...) for job in jobs]``, each job on the next free worker; ``fn`` is a
        module-level function, ``modules`` are imported in a worker before its job (strategies
        registered outside the package). ``progress(job, payload)`` gets each job's progress messages
        (``payload`` None: the job is done).
        Any error, and Ctrl-C, ends the pool before it is raised."""
        self.start(len(jobs))
        out, todo, left = [None] * len(jobs), list(range(len(jobs)))[::-1], len(jobs)
        seconds = [0.0] * len(jobs)
        try:
            while left:
                for w in self._workers:
                    if w.job is None and todo:
                        w.job = todo.pop()
                        w.conn.send((w.job, fn, jobs[w.job], tuple(modules)))
                left -= self._collect(out, seconds, progress)
        except BaseException:
            self.close()
            raise
        self.job_seconds.append(seconds)
        return out

    def _collect(self, out: list, seconds: list, progress) -> int:
        """Handle what the workers sent (waiting up to a second); the jobs finished."""
        busy = [w for w in self._workers if w.job is not None]
        ready = set(wait([w.conn for w in busy] + [w.process.sentinel for w in busy], timeout=1.0))
        finished = 0
        for w in busy:
            if w.conn in ready:
                try:
                    kind, job, payload = w.conn.recv()
                except (EOFError, OSError):  # it died: its pipe closed
                    raise _died(w) from None
                if kind == "progress":
                    if progress is not None:
                        progress(job, payload)
                    continue
                if kind == "error":
                    raise _rebuilt(*payload)
                (out[job], seconds[job]), w.job = payload, None
                finished += 1
                if progress is not None:
                    progress(job, None)
            elif w.process.sentinel in ready:
                raise _died(w)
        return finished

    def close(self) -> None:
        """End every worker: an idle one is asked to stop, a busy one (after an error or Ctrl-C) is
        killed; waits until they are gone."""
        workers, self._workers = self._workers, []
        for w in workers:
            try:
                if w.job is None and w.process.is_alive():
                    w.conn.send(None)
                else:
                    w.process.kill()
            except (OSError, ValueError):
                w.process.kill()
        for w in workers:
            w.process.join(JOIN_TIMEOUT)
            if w.process.is_alive():
                w.process.kill()
                w.process.join()
            w.conn.close()
            w.process.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _died(w: _Worker) -> WorkerError:
    w.process.join(JOIN_TIMEOUT)  # its exit code
    return WorkerError(f"worker process {w.process.pid} ended (exit code {w.process.exitcode}) while it ran job "
                       f"{w.job}: out of memory or killed? Run with --workers 1 (workers=1) to run in one process")


@contextlib.contextmanager
def _main_hidden():
    """The caller's ``__main__`` hidden from "spawn", which would import it in every worker (and run the
    body of a script without an ``if __name__ == "__main__"`` guard again)."""
    main = sys.modules.get("__main__")
    saved = {k: main.__dict__[k] for k in ("__file__", "__spec__") if main is not None and k in main.__dict__}
    try:
        for k in saved:
            if k == "__file__":
                del main.__file__
            else:
                main.__spec__ = None
        yield
    finally:
        for k, v in saved.items():
            setattr(main, k, v)


def _rebuilt(exc, text: str) -> BaseException:
    """The worker's exception, raised here: a warp_shape error as it was; anything else with the
    worker's traceback as a note (it is a defect to report)."""
    if exc is None or not isinstance(exc, BaseException):
        return WorkerError(f"a worker failed: {text.strip().splitlines()[-1]}")
    if not isinstance(exc, WarpShapeError):
        exc.add_note(f"in a worker process:\n{text}")
    return exc


def _portable(exc: BaseException, text: str):
    """``(exc, traceback text)`` if it survives pickling, else ``(None, text)``."""
    try:
        pickle.loads(pickle.dumps(exc))
        return exc, text
    except Exception:  # an exception with unpicklable state: its text goes instead
        return None, text


def _quiet_warp() -> None:
    """Start Warp without its banner or its note that this machine has no CUDA driver (the caller's
    process has said what matters)."""
    wp.config.quiet = True
    wp.config.log_level = wp.LOG_WARNING
    sys.stderr.flush()
    saved, null = os.dup(2), os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 2)
        wp.init()
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(null)


def _end_with_the_caller(parent: int) -> None:
    """End this worker within a second of its caller's end (killed, say), even in the middle of a job."""
    def watch():
        while os.getppid() == parent:
            time.sleep(1.0)
        os._exit(1)
    threading.Thread(target=watch, daemon=True).start()


def _worker_main(conn) -> None:
    """A worker: take jobs ``(id, fn, args, modules)`` until told to stop (None) or the pipe closes."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the caller's to handle: it ends the pool
    _STATE["worker"] = True
    _end_with_the_caller(os.getppid())
    _quiet_warp()
    load_plugins()
    idle = []
    while True:
        try:
            if idle and not conn.poll(IDLE_AFTER):
                _run_idle_task(idle.pop(0))
                continue
            msg = conn.recv()
        except (EOFError, OSError):
            return
        if msg is None:  # the pool ends: nothing is left to send or keep, so skip the interpreter's teardown
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(0)
        if msg[0] == "when_idle":
            idle.append(msg[1])
            continue
        job, fn, args, modules = msg
        last = [0.0]

        def progress(*payload, job=job, last=last):
            now = time.monotonic()
            if now - last[0] >= PROGRESS_EVERY:
                last[0] = now
                try:
                    conn.send(("progress", job, payload))
                except (OSError, ValueError):  # the caller is gone
                    os._exit(1)

        start = time.process_time()
        try:
            for name in modules:
                importlib.import_module(name)
            result = fn(*args, progress=progress)
            reply = ("done", job, (result, time.process_time() - start))
        except BaseException as exc:  # every failure goes back to the caller, who ends the pool
            reply = ("error", job, _portable(exc, traceback.format_exc()))
        try:
            conn.send(reply)
        except (OSError, ValueError):  # the caller is gone
            return


def _run_idle_task(task) -> None:
    try:
        task()
    except Exception:  # only preparation: the job that needs it does the work (and reports its error)
        pass


# ---------------------------------------------------------------------------------- control jobs
def shard_modules(settings, design) -> list[str] | None:
    """The modules a worker imports to know the strategies a control run of ``design`` uses (its
    control method, warm-start law and actuator families, where registered outside the package);
    None when one is defined in ``__main__`` (the job then runs in-process)."""
    method = CONTROL_METHODS[settings.method]
    used = [getattr(method, "law", None) or method, LAWS[settings.warm_start]]
    used += [registry[name] for name, elements in design.actuators.items() if elements
             for registry in (ACTUATOR_FAMILIES, FORCE_FAMILIES) if name in registry]
    modules = []
    for entry in used:
        mod = entry.__module__ if isinstance(entry, type) else type(entry).__module__
        if mod == "__main__":
            return None
        if not mod.startswith("warp_shape") and mod not in modules:
            modules.append(mod)
    return modules


def _per_world(spec, W: int) -> list:
    """One passive spec per world from the spec of a batch (shared indices, or one list per world), as
    ``controller.loop`` reads it."""
    spec = list(spec)
    per_world = len(spec) == W and all(isinstance(s, (list, tuple, np.ndarray, set)) for s in spec)
    return [[spec[w]] if per_world else spec for w in range(W)]


def run_method(method: str, design, targets, *, screen: bool = False, recorder=None, recorder_prefix="control",
               **kwargs) -> list:
    """``CONTROL_METHODS[method].run`` on ``targets`` in this process, or its ``screen`` (``screen``:
    True; a method without one is run and its results screened, ``result.screened``)."""
    m = CONTROL_METHODS[method]
    if screen and hasattr(m, "screen"):
        return m.screen(design, targets, **kwargs)
    out = m.run(design, targets, recorder=recorder, recorder_prefix=recorder_prefix, **kwargs)
    return screened(out) if screen else out


def control_job(method: str, design, target, settings, device, passive_ipams, passive_cells, name, screen=False, *,
                progress=None):
    """One target's control run (a worker's job): ``run_method`` on one world."""
    return run_method(method, design, [target] if isinstance(target, TriMesh) else target, screen=screen, settings=settings, device=device, progress=progress,
                      passive_ipams=passive_ipams, passive_cells=passive_cells, target_names=[name])[0]


def control_sharded(pool: WorkerPool, design, targets: list, *, settings, device: str, progress=None,
                    passive_ipams=(), passive_cells=(), target_names=None, modules=(), screen: bool = False) -> list:
    """``control_many``'s results for the (centred) ``targets`` (``screen``: ``screen_many``'s), one job
    per target on ``pool``'s workers; ``progress(step, max_steps, done, worlds)`` as a batch reports it
    (the furthest step of the jobs running, the targets done)."""
    W = len(targets)
    names = list(target_names) if target_names is not None else [f"target{j}" for j in range(W)]
    pi, pc = _per_world(passive_ipams, W), _per_world(passive_cells, W)
    one = targets.take if isinstance(targets, Problem) else (lambda w: targets[w[0]])
    jobs = [(settings.method, design, one([w]), settings, device, pi[w], pc[w], names[w], screen) for w in range(W)]
    steps, done = np.zeros(W, dtype=np.int64), np.zeros(W, dtype=bool)

    total = [settings.max_steps + settings.max_settle_steps]

    def relay(job, payload):
        if payload is None:
            done[job] = True
        else:
            steps[job], total[0], finished, _ = payload
            done[job] |= finished >= 1
        if progress is not None:
            progress(int(steps.max()), total[0], int(done.sum()), W)

    results = pool.run(control_job, jobs, modules=modules, progress=relay)
    return results if screen else [dataclasses.replace(r, design=design) for r in results]
