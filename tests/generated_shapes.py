"""The generated target shapes the tests judge fits on (warp_shape.benchmarks.generated_shapes)."""

from warp_shape.benchmarks.generated_shapes import NAMES, shape  # noqa: F401
