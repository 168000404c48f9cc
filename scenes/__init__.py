"""Shipped .usda scenes (data); load them with warp_shape.load_scene(name)."""
