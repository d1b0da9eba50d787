"""The benchmark: query sources (simulated, data sets), the one resumable run loop, results and report.

- ``scenario``: the named simulations (``clean``, ``realistic``) and ``--set`` knobs;
- ``queries``, ``seg_errors``, ``shadows``, ``perception_sim``, ``depth_sim``: the query simulator
  (segmentation and depth errors); ``reality`` (with ``building_changes``, ``occluders``,
  ``terrain_relief``, ``footprints``, ``meshes``): the simulated reality the queries see (reality != map);
- ``sources``: the ``QuerySource`` protocol and ``SimulatedSource``; ``dataset_source``: a LoD-Loc data set;
- a folder of photos (``semcityloc run``): ``photo_spec`` (the run), ``photo_inputs`` (each photo's inputs
  checked before it), ``photo_focal`` (a camera's focal length from its flight; ``focal_cache``),
  ``photo_source`` (the photos as queries), ``photo_exports`` (COLMAP, geotags, GeoJSON);
- ``methods``: the one table of methods by name (SemCityLoc, its ablations, the baselines);
- ``spec``: ``BenchmarkSpec`` (a simulated run) and the models it loads;
- ``run``: ``run_queries`` / ``run_benchmark``, the one loop (resume, workers, progress);
- ``results``: ``results.csv`` rows, details, summary; ``runfiles``: the run folder, atomic writes;
- ``report``: the paper's tables and figures from run folders (with ``report_runs``: a run folder read
  and runs described, ``report_tables``: the Markdown/CSV tables, ``report_plots``: the figures).
"""
