"""Files for people and tools: EXR rasters, PNG images, matplotlib figures, .npz archives."""
