"""Warp kernels and functions of warp_shape (installed as ``warp_shape.kernels``).

Kernels know nothing of IO. Parameters are grouped by ``# Model:`` / ``# State in:`` /
``# Control:`` / ``# Out:`` comments; every array documents its shape.
"""
