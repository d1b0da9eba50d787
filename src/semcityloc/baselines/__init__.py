"""Baselines compared with SemCityLoc on the same benchmark (issue 6, docs/baselines.md).

- ``WireframeLocalizer``: LoD-Loc-style wireframe alignment (model edge points vs an edge-probability
  map; 3-stage 4D grid search, damped Gauss-Newton refinement).
- ``SilhouetteLocalizer``: LoD-Loc v2-style building-silhouette IoU on SemCityLoc's own search.
- ``simulate_edge_map`` / ``EdgeMapSimulator``: the benchmark's simulated wireframe extractor;
  ``image_edge_map``: gradient edges of a real image.
- ``BASELINE_METHODS``: ``silhouette`` and ``lodloc-wireframe`` (``make_baseline_method``) by name, which
  the benchmark's method table (``benchmark.methods.METHODS``) lists beside SemCityLoc's.
"""

from semcityloc.baselines.edge_sim import EDGE_PRESETS, EdgeMapSimulator, image_edge_map, simulate_edge_map
from semcityloc.baselines.edges import ModelEdges, extract_edges
from semcityloc.baselines.methods import BASELINE_METHODS, BASELINES, make_baseline_method
from semcityloc.baselines.silhouette import SilhouetteLocalizer
from semcityloc.baselines.wireframe import REASON_NO_EDGES, WireframeConfig, WireframeLocalizer

__all__ = [
    "BASELINES",
    "BASELINE_METHODS",
    "EDGE_PRESETS",
    "EdgeMapSimulator",
    "ModelEdges",
    "REASON_NO_EDGES",
    "SilhouetteLocalizer",
    "WireframeConfig",
    "WireframeLocalizer",
    "extract_edges",
    "image_edge_map",
    "make_baseline_method",
    "simulate_edge_map",
]
