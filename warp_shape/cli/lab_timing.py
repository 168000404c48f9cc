"""The lab's clock flags shared by ``design`` and ``export``: the syringe pump's flow limit, the
valves' slew limit and the valve CSV's sample grid (``io.valve.ValveTiming``). The valve CSV, the
USD animations and the figures all follow them."""

from __future__ import annotations

from ..io.valve import (DEFAULT_MAX_FLOW_ML_S, DEFAULT_MAX_SLEW_KPA_S, DEFAULT_RATE_HZ, MAX_VALVE_RATE_HZ,
                        MIN_VALVE_FLOW_ML_S, MIN_VALVE_SLEW_KPA_S, ValveTiming)
from .options import add_bounded

__all__ = ["add_timing_args", "timing_from_args"]


def add_timing_args(sp) -> None:
    """``--max-flow``, ``--max-slew`` and ``--rate`` (bounded; 0 turns each off)."""
    add_bounded(sp, "--max-flow", MIN_VALVE_FLOW_ML_S, 1e9, zero=True, type=float, default=DEFAULT_MAX_FLOW_ML_S,
                metavar="ML_PER_S", help=f"syringe pump: the chamber's air changes by at most this many mL/s in the "
                                         f"lab schedule (default {DEFAULT_MAX_FLOW_ML_S:g}); 0: no limit")
    add_bounded(sp, "--max-slew", MIN_VALVE_SLEW_KPA_S, 1e9, zero=True, type=float, default=DEFAULT_MAX_SLEW_KPA_S,
                metavar="KPA_PER_S", help=f"valves: no pressure changes faster than this many kPa/s in the lab "
                                          f"schedule (default {DEFAULT_MAX_SLEW_KPA_S:g}); 0: no limit (with "
                                          f"--max-flow 0: the simulated pace)")
    add_bounded(sp, "--rate", 1e-3, MAX_VALVE_RATE_HZ, zero=True, type=float, default=DEFAULT_RATE_HZ, metavar="HZ",
                help=f"valve CSV samples per second, every control step on the grid (default {DEFAULT_RATE_HZ:g}); "
                     f"0: one row per control step")


def timing_from_args(args):
    """The ``ValveTiming`` of the flags (0 turns a limit off)."""
    return ValveTiming(rate_hz=args.rate or None, max_slew_kpa_s=args.max_slew or None,
                       max_flow_ml_s=args.max_flow or None)
