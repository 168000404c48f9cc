"""Gradients in the design space: the differentiable replay of a control sequence (docs/gradients.md)."""

from .replay import DifferentiableReplay, ReplayGradient, ReplayPlan

__all__ = ["DifferentiableReplay", "ReplayGradient", "ReplayPlan"]
