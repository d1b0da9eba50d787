"""Reading and writing the files the pipeline exchanges with users: image files (label PNGs, depth maps,
``images``) and whole-or-absent writes (``files``)."""
