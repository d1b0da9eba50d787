"""Reading and writing the image files the pipeline exchanges with users (label PNGs, depth maps)."""
