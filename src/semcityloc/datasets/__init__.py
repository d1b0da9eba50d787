"""Users' data: LoD-Loc data set folders, COLMAP models, DJI image metadata. Readers and writers only.

- ``lodloc``: LoD-Loc's layout (UAVD4L-LoD, Swiss-EPFL, the demo folder) -> queries with Camera and Pose;
- ``colmap``: COLMAP ``cameras`` / ``images`` / ``points3D``, text and binary, read and write
  (``colmap_pycolmap``: the optional bridge to ``pycolmap.Reconstruction``);
- ``dji_metadata``: a DJI photo's XMP / EXIF tags, read and checked; ``dji_camera``: its camera and lens
  distortion from them;
- ``dji``: GPS and gimbal angles of a DJI photo -> a prior pose in a city model's CRS, heights handled or
  flagged, its uncertainty, and the way back (a geotag);
- ``geodesy``: WGS 84 positions and heights into a city model's CRS (vertical datum, geoid separation, grid
  convergence), with pyproj;
- ``overlay``: the model's visible edges at a pose over a real image, and an image-edge alignment score.

The benchmark over such a data set lives in ``benchmark.dataset_source``.
"""
