"""Control methods as strategies, and the controller's entry points ``control_many`` / ``control``.

A control method has ``name``, a one-line ``summary``, ``refines`` (whether it runs a model-based
refinement after a law, which the progress bar shows) and
``run(design, targets, *, settings, device, recorder, progress, passive_ipams, passive_cells,
target_names, recorder_prefix) -> [ControlResult]`` over centred targets. ``CONTROL_METHODS`` holds
them by name; ``ControlSettings.method`` picks one. Built in: ``"inverse"`` (model-based,
docs/inverse_control.md) and one method per control law (``"paper"``). ``register_law`` registers a
law and the method that runs it; ``register_control_method`` any other method.
"""

from __future__ import annotations

from ..display import Design
from ..errors import DesignError
from ..mesh import TriMesh
from ..simulation_settings import settings_or_default
from .inverse import control_inverse, predict_inverse
from .laws import PaperLaw
from .loop import run_law
from .problem import as_problem
from .result import ControlResult, ScreenResult
from .control_settings import CONTROL_METHODS, LAWS, ControlSettings
from .shard import control_sharded, run_method, shard_modules, worker_pool

__all__ = ["LawMethod", "InverseMethod", "register_law", "register_control_method", "control_many", "control",
           "screen_many", "CONTROL_METHODS"]


class LawMethod:
    """The control method that runs one control law alone (``controller.loop.run_law``)."""

    refines = False

    def __init__(self, law):
        self.law = law
        self.name, self.summary = law.name, law.summary

    def run(self, design, targets, *, settings, **kwargs) -> list[ControlResult]:
        return run_law(design, targets, self.law, settings=settings, **kwargs)


class InverseMethod:
    """Model-based control warm-started by the law ``settings.warm_start`` (``controller.inverse``)."""

    name = "inverse"
    summary = "the paper's law as warm start, then model-based control of air, IPAMs and jam plan (default)"
    refines = True

    def _warm(self, design, targets, settings, device, progress, passive_ipams, passive_cells, target_names):
        return run_law(design, targets, LAWS[settings.warm_start], settings=settings.replace(method=settings.warm_start),
                       device=device, progress=progress, passive_ipams=passive_ipams, passive_cells=passive_cells,
                       target_names=target_names, keep_simulator=True)

    def run(self, design, targets, *, settings, device, progress=None, passive_ipams=(), passive_cells=(),
            target_names=None, **kwargs) -> list[ControlResult]:
        targets = as_problem(targets, target_names, device=device, centre=False)  # one sampler for both stages
        warm, sim = self._warm(design, targets, settings, device, progress, passive_ipams, passive_cells, target_names)
        return control_inverse(design, targets, device=device, settings=settings, progress=progress,
                               passive_ipams=passive_ipams, passive_cells=passive_cells, target_names=target_names,
                               warm_start=warm, warm_simulator=sim, **kwargs)

    def screen(self, design, targets, *, settings, device, progress=None, passive_ipams=(), passive_cells=(),
               target_names=None) -> list[ScreenResult]:
        """The fit ``run`` would reach, predicted without the plans' trajectories (``predict_inverse``)."""
        targets = as_problem(targets, target_names, device=device, centre=False)  # one sampler for both stages
        warm, sim = self._warm(design, targets, settings, device, progress, passive_ipams, passive_cells, target_names)
        return predict_inverse(design, device=device, settings=settings, warm_start=warm, warm_simulator=sim,
                               targets=targets)


def register_control_method(method, *, replace: bool = False):
    """Make ``method`` (see the module docstring) selectable as ``ControlSettings.method``, in
    ``ws.control``, ``ws.design`` and ``warp-shape control --method``; returns it."""
    if not callable(getattr(method, "run", None)):
        raise DesignError(f"a control method needs a run(design, targets, *, settings, ...) method, got {method!r}")
    return CONTROL_METHODS.register(method, replace=replace)


def register_law(law, *, replace: bool = False):
    """Register the control law ``law`` (a class with ``name``, ``summary``, ``update_phase`` and
    ``step``, built as ``law(settings, device_constants, passive_ipams, passive_cells)``; see
    ``controller.laws``) in ``LAWS``, and the control method of the same name that runs it; returns it."""
    for attr in ("update_phase", "step"):
        if not callable(getattr(law, attr, None)):
            raise DesignError(f"a control law needs a {attr} method; {law!r} has none")
    LAWS.register(law, replace=replace)
    register_control_method(LawMethod(law), replace=replace)
    return law


register_control_method(InverseMethod())
register_control_method(LawMethod(PaperLaw))


def control_many(design: Design, targets, *, device: str = "cpu", settings: ControlSettings | None = None,
                 recorder=None, progress=None, passive_ipams=(), passive_cells=(), target_names=None,
                 recorder_prefix: str = "control", method: str | None = None, **overrides) -> list[ControlResult]:
    """Drive ``design`` to every target at once (one simulated world per target, each centred on its
    volume centroid first) with the control method ``method`` (default ``settings.method``; the
    names in ``CONTROL_METHODS``).

    ``passive_ipams`` / ``passive_cells``: actuators left out of this control sequence (indices for
    every target, or one list per target): a passive IPAM is masked out of its world (no force; its
    recorded pressure tracks its length), a passive cell never jams (paper, section V-C).
    ``progress(step, max_steps, done, worlds)`` is called every control step; ``recorder`` logs the
    run. Keyword overrides go to ``settings``.

    On the CPU, with ``settings.workers`` other than 1 (0, the default: every core) or inside a run's
    ``worker_pool``, each target is its own job on a worker process (``controller.shard``; not with a
    ``recorder``): its result is that of ``control_many(design, [target])``, bit for bit.
    """
    return _many(design, targets, device=device, settings=settings, recorder=recorder, progress=progress,
                 passive_ipams=passive_ipams, passive_cells=passive_cells, target_names=target_names,
                 recorder_prefix=recorder_prefix, method=method, overrides=overrides, screen=False)


def screen_many(design: Design, targets, *, device: str = "cpu", settings: ControlSettings | None = None,
                progress=None, passive_ipams=(), passive_cells=(), target_names=None) -> list[ScreenResult]:
    """What ``control_many`` with the same arguments would reach per target, estimated at less cost
    where the control method has a ``screen`` (``"inverse"``: the fit its refinement predicts in its
    scratch settles, no trajectory run; docs/inverse_control.md), else measured by running it: one
    ``ScreenResult`` per target, sharded as ``control_many`` is (a job's estimate is that of
    ``screen_many(design, [target])``, bit for bit)."""
    return _many(design, targets, device=device, settings=settings, recorder=None, progress=progress,
                 passive_ipams=passive_ipams, passive_cells=passive_cells, target_names=target_names,
                 recorder_prefix="control", method=None, overrides={}, screen=True)


def _many(design, targets, *, device, settings, recorder, progress, passive_ipams, passive_cells, target_names,
          recorder_prefix, method, overrides, screen: bool) -> list:
    if not isinstance(design, Design):
        raise DesignError(f"control needs a ws.Design, got {type(design).__name__}")
    targets = as_problem(targets, target_names, device=device)  # centred once; a run's problem as it is
    settings = settings_or_default(settings, ControlSettings, "settings")
    if method is not None:
        overrides["method"] = method
    if overrides:
        settings = settings.replace(**overrides)
    kwargs = dict(settings=settings, device=device, progress=progress, passive_ipams=passive_ipams,
                  passive_cells=passive_cells, target_names=target_names)
    with worker_pool(settings.workers) as pool:
        modules = shard_modules(settings, design) if pool is not None else None
        if modules is not None and len(targets) > 1 and recorder is None and str(device).startswith("cpu"):
            return control_sharded(pool, design, targets, modules=modules, screen=screen, **kwargs)
        return run_method(settings.method, design, targets, screen=screen, recorder=recorder,
                          recorder_prefix=recorder_prefix, **kwargs)


def control(design: Design, target: TriMesh, *, device: str = "cpu", settings: ControlSettings | None = None,
            recorder=None, progress=None, passive_ipams=(), passive_cells=(), target_name: str = "target",
            method: str | None = None, **overrides) -> ControlResult:
    """Drive ``design`` to one ``target`` (centred on its volume centroid first) with ``method``
    (default ``settings.method``)."""
    return control_many(design, [target], device=device, settings=settings, recorder=recorder, progress=progress,
                        passive_ipams=passive_ipams, passive_cells=passive_cells, target_names=[target_name],
                        method=method, **overrides)[0]
