"""Users' data: LoD-Loc data set folders, COLMAP models, DJI image metadata. Readers and writers only.

- ``lodloc``: LoD-Loc's layout (UAVD4L-LoD, Swiss-EPFL, the demo folder) -> queries with Camera and Pose;
- ``colmap``: COLMAP ``cameras`` / ``images`` / ``points3D``, text and binary, read and write
  (``colmap_pycolmap``: the optional bridge to ``pycolmap.Reconstruction``);
- ``dji``: GPS and gimbal angles of a DJI photo -> a prior pose in a city model's CRS, heights handled or
  flagged;
- ``overlay``: the model's visible edges at a pose over a real image, and an image-edge alignment score.

The benchmark over such a data set lives in ``benchmark.dataset_source``.
"""
