"""Count Warp kernel launches (a test utility): direct launches, replayed recorded launches, graph launches."""

from __future__ import annotations

import warp as wp

__all__ = ["LaunchCounter", "count_control_launches"]


class LaunchCounter:
    """Context manager that counts Warp launches while it is active.

    ``count``: every launch (``wp.launch``, a replayed recorded ``wp.Launch`` and a graph
    ``wp.capture_launch``). ``kernels``: ``wp.launch`` calls per kernel key (recorded and graph
    replays are not Python launches of a kernel and do not appear there).
    """

    def __init__(self):
        self.count = 0
        self.kernels: dict[str, int] = {}
        self._saved = None

    def __enter__(self) -> "LaunchCounter":
        real_launch, real_replay, real_graph = wp.launch, wp.Launch.launch, wp.capture_launch
        self._saved = (real_launch, real_replay, real_graph)

        def launch(*a, **k):
            self.count += 1
            kernel = a[0] if a else k.get("kernel")
            key = getattr(kernel, "key", str(kernel))
            self.kernels[key] = self.kernels.get(key, 0) + 1
            return real_launch(*a, **k)

        def replay(cmd, *a, **k):
            self.count += 1
            return real_replay(cmd, *a, **k)

        def graph(*a, **k):
            self.count += 1
            return real_graph(*a, **k)

        wp.launch, wp.Launch.launch, wp.capture_launch = launch, replay, graph
        return self

    def __exit__(self, *exc) -> None:
        wp.launch, wp.Launch.launch, wp.capture_launch = self._saved


def count_control_launches(design, target, recorder=None, **control_kwargs) -> int:
    """Warp launches of one ``ws.control`` run (with or without a recorder)."""
    from warp_shape.controller import control

    with LaunchCounter() as c:
        control(design, target, recorder=recorder, **control_kwargs)
    return c.count
