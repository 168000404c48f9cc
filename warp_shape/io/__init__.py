"""Input and output at the edge of warp_shape: USD scenes and animations, rerun recordings, figures, files.

Nothing below the I/O layer imports this package: the simulator, the controller and the designer
return plain data, and these modules turn it into files.
"""
