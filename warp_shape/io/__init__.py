"""File and display adapters at the edge of warp_shape: scenes, recordings, figures and outputs."""
