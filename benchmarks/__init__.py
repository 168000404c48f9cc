"""warp_shape's benchmark suite and its NumPy baseline (installed as ``warp_shape.benchmarks``).

Run them with ``warp-shape bench sim|tradeoff|design|peer|rays``. They are not part of the public
API: ``import warp_shape`` does not import them.
"""
