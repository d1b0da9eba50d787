"""The baselines as localization methods: ``BASELINE_METHODS``, joined with SemCityLoc's in the benchmark's
method table (``benchmark.methods.METHODS``).

Why here: the method table only needs a factory per name; keeping the baselines' wiring (edge-map
simulation per query, seeds, quality mapping) next to the baselines keeps the table free of baseline
details. Nothing is registered when this module is imported: the benchmark layer lists this table.

- ``silhouette``: ``SilhouetteLocalizer`` with the run's localizer preset (depth is never used).
- ``lodloc-wireframe``: ``WireframeLocalizer`` on an edge map simulated for each query from its TRUE
  pose (``EdgeMapSimulator``, i.e. the map model's edges as a perfect-geometry extractor would see them,
  degraded by the quality preset) with the query's background pixels that are not sky (trees, cars:
  ``labels == 0`` where the depth is finite) as occluders. Random stream ``[config.seed, q.index,
  EDGE_STREAM]``. The quality follows the query's segmentation quality (``EDGE_QUALITY_FOR_SEG``)
  unless ``edge_quality`` is given. A query without a true pose (a user's photo) has no simulated edge
  map: the wireframe baseline is for benchmarks only.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

import numpy as np

from semcityloc.baselines.edge_sim import EDGE_PRESETS, EdgeMapSimulator
from semcityloc.baselines.edges import extract_edges
from semcityloc.baselines.silhouette import SilhouetteLocalizer
from semcityloc.baselines.wireframe import WireframeConfig, WireframeLocalizer
from semcityloc.citymodel.model import CityModel
from semcityloc.classes import SemanticClass
from semcityloc.errors import ParameterError, unknown_choice
from semcityloc.io.images import resize_nearest
from semcityloc.localization.config import LocalizerConfig
from semcityloc.localization.methods import MethodEntry, QueryRecord
from semcityloc.localization.result import LocalizationResult
from semcityloc.render.scene import RenderScene

SILHOUETTE = "silhouette"
WIREFRAME = "lodloc-wireframe"
BASELINES = (SILHOUETTE, WIREFRAME)
EDGE_STREAM = 5  # the query simulator uses streams 0-4 of [seed, index, stream]

# Segmentation quality of the run (QueryConfig.seg_quality) -> simulated wireframe quality: the same
# perception level for both kinds of query input. A judgement call (docs/baselines.md).
EDGE_QUALITY_FOR_SEG = {"perfect": "clean", "trained": "trained", "medium": "noisy", "zero-shot": "noisy"}


def occluder_mask(labels: np.ndarray, depth: np.ndarray | None, height: int, width: int) -> np.ndarray:
    """(height, width) bool: background-labelled pixels that are not sky (finite depth where known)."""
    lab = np.asarray(labels)
    occ = lab == SemanticClass.BACKGROUND
    if depth is not None and np.shape(depth) == lab.shape:
        occ &= np.isfinite(np.asarray(depth, dtype=np.float64))
    if occ.shape != (height, width):
        occ = resize_nearest(occ, width, height)
    return occ


class SilhouetteMethod:
    """Benchmark method ``silhouette``."""

    def __init__(self, name: str, map_model: CityModel, config: LocalizerConfig):
        self.name = name
        self.localizer = SilhouetteLocalizer(map_model, config)

    def localize(self, q: QueryRecord) -> LocalizationResult:
        """The silhouette search on the query's labels alone (its depth is never used)."""
        return self.localizer.localize(
            q.camera,
            q.prior_pose_local,
            q.labels,
            None,
            prior_uncertainty=getattr(q, "prior_uncertainty", None),
        )


class WireframeMethod:
    """Benchmark method ``lodloc-wireframe`` (module docstring)."""

    def __init__(
        self,
        name: str,
        map_model: CityModel,
        config: LocalizerConfig,
        wireframe: WireframeConfig | None = None,
        edge_quality: str | None = None,
    ):
        if edge_quality is not None and edge_quality not in EDGE_PRESETS:
            raise unknown_choice("edge-map quality", edge_quality, EDGE_PRESETS)
        self.name = name
        self.seed = int(config.seed)
        self.edge_quality = edge_quality
        self.localizer = WireframeLocalizer(map_model, wireframe or WireframeConfig(seed=self.seed))
        self.simulator = EdgeMapSimulator(map_model, self.localizer.scene, self.localizer.edges)
        self.edge_source = "map"

    def attach_reality(self, reality_model: CityModel, reality_scene: RenderScene) -> None:
        """Simulate the edge maps from the benchmark's reality (the world the query images show: its
        buildings with their geometric errors and roof structures, trees and cars occluding them)
        instead of from the map model. Window and door frames are left out: LoD-Loc's extractor is
        trained to predict the map's wireframe, not facade detail. The runner should call this with its
        simulator's reality (in the map's local frame); without it the edge maps come from the map model
        (exact geometry)."""
        edges = extract_edges(reality_model, self.localizer.config.crease_deg).physical()
        self.simulator = EdgeMapSimulator(reality_model, reality_scene, edges)
        self.edge_source = "reality"

    def quality_for(self, q: QueryRecord) -> str:
        """The edge-map quality preset: the fixed one, else the one matching the query's seg_quality."""
        if self.edge_quality is not None:
            return self.edge_quality
        return EDGE_QUALITY_FOR_SEG.get(str(q.meta.get("seg_quality", "trained")), "trained")

    def edge_map(self, q: QueryRecord) -> np.ndarray:
        """The simulated wireframe-extractor output of query ``q`` (deterministic per query)."""
        cam = q.camera
        occ = occluder_mask(q.labels, q.depth, cam.height, cam.width)
        if q.true_pose_local is None:
            raise ParameterError("the lodloc-wireframe baseline simulates its edge map from a true pose")
        rng = np.random.default_rng([self.seed, int(q.index), EDGE_STREAM])
        return self.simulator.simulate(cam, q.true_pose_local, self.quality_for(q), rng, occ)

    def localize(self, q: QueryRecord) -> LocalizationResult:
        """LoD-Loc's wireframe search on the query's simulated edge map (``edge_map``)."""
        return self.localizer.localize(q.camera, q.prior_pose_local, self.edge_map(q))


def make_baseline_method(
    name: str, map_model: CityModel, config: LocalizerConfig | None = None
) -> SilhouetteMethod | WireframeMethod:
    """Factory for the method table: ``name`` is one of ``BASELINES``."""
    config = config if config is not None else LocalizerConfig.preset("default")
    if name == SILHOUETTE:
        return SilhouetteMethod(name, map_model, config)
    if name == WIREFRAME:
        return WireframeMethod(name, map_model, config)
    raise unknown_choice("baseline", name, BASELINES)


# The baselines by name; the wireframe aligns the model's own edges, so it searches the model as it is.
BASELINE_METHODS: Mapping[str, MethodEntry] = MappingProxyType(
    {
        SILHOUETTE: MethodEntry(make_baseline_method),
        WIREFRAME: MethodEntry(make_baseline_method, map_eaves=False),
    }
)
