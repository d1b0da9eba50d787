"""SemCityLoc and its ablations as methods, and what a method is (the full table by name is
``benchmark.methods``).

Why a table: the benchmark, the CLI and the report name methods by string (``--method no-depth``). A
method is built once per process for one map (a ``MethodEntry``'s factory: ``factory(name, map_model,
config)``) and then localizes many queries. This module lists SemCityLoc and its ablations
(``LOCALIZER_METHODS``); ``baselines.methods.BASELINE_METHODS`` lists the baselines; the benchmark layer,
above both, joins them into the one table every caller asks (``benchmark.methods.METHODS``). Nothing is
registered as a side effect of an import, so what a name means never depends on what was imported first.

A method localizes a query record (``QueryRecord``): the camera, the prior in the map model's LOCAL
frame, the query mask and optional depth; simulated queries also carry their true pose, which only
baselines that simulate their own input (the wireframe's edge map) read.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Protocol

import numpy as np

from semcityloc.citymodel.model import CityModel
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose
from semcityloc.geometry.uncertainty import PriorUncertainty
from semcityloc.localization.config import ABLATION_FLAGS, LocalizerConfig
from semcityloc.localization.localize import Localizer
from semcityloc.localization.result import LocalizationResult
from semcityloc.render.scene import RenderScene


class QueryRecord(Protocol):
    """What a method reads of a query (``benchmark.queries.BenchmarkQuery`` is one)."""

    index: int
    camera: Camera
    prior_pose_local: Pose
    true_pose_local: Pose | None
    labels: np.ndarray
    depth: np.ndarray | None
    meta: dict[str, Any]
    prior_uncertainty: PriorUncertainty | None  # optional attribute; None or absent: config.prior_uncertainty


class Method(Protocol):
    """What the benchmark calls for every query."""

    name: str

    def localize(self, q: QueryRecord) -> LocalizationResult:
        """The pose of one query (its camera, prior and inputs) as a ``LocalizationResult``."""


MethodFactory = Callable[[str, CityModel, LocalizerConfig], Method]


class LocalizerMethod:
    """SemCityLoc (``semcityloc``) or one of its ablations on a ``Localizer`` built once."""

    def __init__(
        self, name: str, map_model: CityModel, config: LocalizerConfig, scene: RenderScene | None = None
    ):
        self.name = name
        self.config = config.with_ablation(name)
        self.localizer = Localizer(map_model, self.config, scene=scene)

    def localize(self, q: QueryRecord) -> LocalizationResult:
        """The query localized by this method's ``Localizer`` with the query's own prior uncertainty when it
        has one.
        """
        return self.localizer.localize(
            q.camera,
            q.prior_pose_local,
            q.labels,
            q.depth,
            prior_uncertainty=getattr(q, "prior_uncertainty", None),
        )


@dataclass(frozen=True)
class MethodEntry:
    """A method of the table: how to build it (``factory(name, map_model, localizer_config) -> Method``)
    and which map it searches. ``map_eaves``: the localizer config's map (the model with ``map_eaves_m`` of
    eaves, ``localizer_scene``) rather than the model as it is (the wireframe baseline, whose edges are the
    model's own)."""

    factory: MethodFactory
    map_eaves: bool = True

    def searched_map(self, config: LocalizerConfig) -> dict[str, Any]:
        """The map this method searches with ``config``, as a run records it (``run.json``'s
        ``searched_map``) and its drawings read it (``benchmark.found_map``): ``eaves_m``, the eaves on its
        pitched roofs, and ``flat_roofs``, ``config.map_eaves_flat_roofs`` (``"off"`` without eaves)."""
        if not self.map_eaves or not config.map_eaves_m > 0.0:
            return {"eaves_m": 0.0, "flat_roofs": "off"}
        return {"eaves_m": float(config.map_eaves_m), "flat_roofs": str(config.map_eaves_flat_roofs)}


# Order of the paper's main table: the full method first, then the ablations.
ABLATIONS: tuple[str, ...] = tuple(ABLATION_FLAGS)
# SemCityLoc and its ablations by name (read-only; the whole table: ``benchmark.methods.METHODS``).
LOCALIZER_METHODS: Mapping[str, MethodEntry] = MappingProxyType(
    {name: MethodEntry(LocalizerMethod) for name in ABLATIONS}
)
