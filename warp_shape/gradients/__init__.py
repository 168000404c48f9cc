"""Gradients in the design space: the differentiable replay of a control sequence and ``ws.gradient``
(docs/gradients.md)."""

from .api import GRADIENT_PARAMETERS, Gradient, gradient
from .differentiable_replay import DifferentiableReplay, ReplayGradient, ReplayPlan

__all__ = ["gradient", "Gradient", "GRADIENT_PARAMETERS", "DifferentiableReplay", "ReplayGradient", "ReplayPlan"]
