"""Where a sweep's runs execute: one after another in this process (``serial``), or one Ray task each (``ray``).

Ray (``pip install 'warp-shape[cluster]'``) starts a local instance with ``workers`` CPUs by default,
or joins a running cluster at ``address`` (``ray start --head`` on the head node, then
``--address HOST:6379`` or ``auto``). Each run is one task asking for one CPU, and one GPU when the
device is CUDA; at most ``workers`` tasks are in flight. A task whose worker process dies is retried
``retries`` times by Ray, then recorded as failed; the sweep goes on.

A local instance listens on the loopback interface only (its GCS, raylet, object manager, agents and
workers bind 127.0.0.1): Ray's single-machine mode, which it otherwise keeps for Windows and macOS.
Nothing of it can be reached, or joined, from another machine.
"""

from __future__ import annotations

import logging
import os
import socket
import time
from contextlib import contextmanager

from .params import SweepError
from .run import error_row

__all__ = ["BACKENDS", "run_serial", "run_ray", "require_ray", "start_ray", "check_address"]

BACKENDS = ("ray", "serial")

#: Ray's switch between its single-machine mode ("0": every server on 127.0.0.1) and cluster mode
CLUSTER_MODE_ENV = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"
LOOPBACK = ("127.0.0.1", "::1")

INSTALL_HINT = ("Ray is not installed: install the cluster extra, pip install 'warp-shape[cluster]' "
                "(or pip install 'ray>=2.60'), or run the sweep with --backend serial")


def require_ray():
    """The ``ray`` module, or a ``SweepError`` saying how to install it."""
    try:
        import ray
    except ImportError:
        raise SweepError(INSTALL_HINT) from None
    return ray


def check_address(address: str, timeout: float = 5.0) -> None:
    """A quick ``SweepError`` when nothing listens at a HOST:PORT address (Ray itself retries for minutes)."""
    if address in ("auto", "local") or "://" in address:
        return
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit():
        raise SweepError(f"--address must be HOST:PORT (e.g. 10.0.0.5:6379), auto or ray://HOST:PORT, got {address!r}")
    try:
        socket.create_connection((host, int(port)), timeout=timeout).close()
    except OSError as exc:
        raise SweepError(f"no Ray cluster answers at {address} ({exc}); start its head there with "
                         f"`ray start --head --port {port}`, or leave out --address for a local instance") from None


@contextmanager
def _single_machine_mode(ray):
    """Ray's single-machine mode while a local instance starts: its node address is the loopback one, so
    every server it starts binds there. Ray reads the switch at import (``ray_constants``, this process)
    and from the environment (the processes it starts); both are restored afterwards."""
    constants = ray._private.ray_constants
    saved_env, saved_flag = os.environ.get(CLUSTER_MODE_ENV), constants.ENABLE_RAY_CLUSTER
    os.environ[CLUSTER_MODE_ENV] = "0"
    constants.ENABLE_RAY_CLUSTER = False
    try:
        yield
    finally:
        constants.ENABLE_RAY_CLUSTER = saved_flag
        if saved_env is None:
            os.environ.pop(CLUSTER_MODE_ENV, None)
        else:
            os.environ[CLUSTER_MODE_ENV] = saved_env


RAY_TOKEN_LOGGER = "ray._private.authentication.authentication_token_setup"


class _QuietTokenNotice(logging.Filter):
    """Drops Ray's notice that a local instance uses token authentication (Ray >= 2.59's default, kept:
    docs/sweeps.md says so once), printed on every start; its other messages pass."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not record.getMessage().startswith("Token authentication is enabled")


@contextmanager
def quiet_token_notice():
    """Ray's token-authentication notice left out while a local instance starts."""
    logger, quiet = logging.getLogger(RAY_TOKEN_LOGGER), _QuietTokenNotice()
    logger.addFilter(quiet)
    try:
        yield
    finally:
        logger.removeFilter(quiet)


def start_ray(address: str | None, workers: int | None) -> tuple[bool, float]:
    """Join ``address`` or start a local Ray instance with ``workers`` CPUs (this machine's count by
    default); returns (started here, seconds taken). An instance already running in this process is used."""
    ray = require_ray()
    if ray.is_initialized():
        return False, 0.0
    if address:
        check_address(address)
    t0 = time.perf_counter()
    common = dict(include_dashboard=False, logging_level="warning", log_to_driver=False,
                  runtime_env={"env_vars": {"OMP_NUM_THREADS": "1"}})
    try:
        if address:
            ray.init(address=address, **common)
        else:
            # "local": a new instance even where a cluster's address is on record (RAY_ADDRESS, a stale file)
            with _single_machine_mode(ray), quiet_token_notice():
                ray.init(address="local", num_cpus=workers or os.cpu_count() or 1, **common)
    except (ConnectionError, RuntimeError, ValueError, ray.exceptions.RayError) as exc:
        where = f"the Ray cluster at {address!r}" if address else "a local Ray instance"
        hint = ("start its head with `ray start --head` and pass --address HOST:6379 (or auto on a node); Ray "
                ">= 2.59 guards a cluster with a token: set RAY_AUTH_MODE=token with the cluster's token in "
                "~/.ray/auth_token (docs/sweeps.md)") if address else "see docs/sweeps.md"
        raise SweepError(f"could not start or join {where}: {' '.join(str(exc).split())[:300]}. {hint}") from None
    node_ip = ray.util.get_node_ip_address()
    if not address and node_ip not in LOOPBACK:
        ray.shutdown()
        raise SweepError(f"this Ray ({ray.__version__}) would run its local instance on {node_ip}, reachable from "
                         f"other machines; run the sweep with --backend serial, or on a cluster with --address")
    return True, time.perf_counter() - t0


def run_serial(tasks, run_fn, on_done) -> None:
    """Every task in this process, one after another; ``on_done(task, row, files)`` after each."""
    for task in tasks:
        row, files = run_fn(task)
        on_done(task, row, files)


def _crash_row(task, exc) -> tuple[dict, dict]:
    name = type(exc).__name__
    text = str(exc).strip().splitlines()
    return error_row(task, f"{name}: {text[0] if text else 'the worker running this run died'}"), {}


def run_ray(tasks, run_fn, on_done, *, workers: int | None = None, address: str | None = None,
            gpus_per_run: float = 0.0, retries: int = 1) -> float:
    """Every task as one Ray task, at most ``workers`` at a time; ``on_done(task, row, files)`` in the
    driver as each finishes. Returns the seconds Ray took to start (0 when already running)."""
    ray = require_ray()
    started, startup = start_ray(address, workers)
    try:
        if workers is None:
            workers = max(1, int(ray.cluster_resources().get("CPU", 1)))
        remote = ray.remote(run_fn).options(num_cpus=1, num_gpus=gpus_per_run, max_retries=retries)
        queue = list(tasks)
        pending: dict = {}
        while queue or pending:
            while queue and len(pending) < workers:
                task = queue.pop(0)
                pending[remote.remote(task)] = task
            ready, _ = ray.wait(list(pending), num_returns=1)
            for ref in ready:
                task = pending.pop(ref)
                try:
                    row, files = ray.get(ref)
                except ray.exceptions.RayError as exc:  # the worker died (killed, out of memory, node lost)
                    row, files = _crash_row(task, exc)
                on_done(task, row, files)
    finally:
        if started:  # a local instance stops; a cluster is only left
            ray.shutdown()
    return startup
