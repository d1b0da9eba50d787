"""The table of localization methods by name: SemCityLoc, its ablations, and the baselines.

Why a table: the benchmark, the CLI and the report name methods by string (``--method no-depth``). A
method is built once per process for one map (``get_method(name, map_model, config)``) and then localizes
many queries. SemCityLoc and its ablations are registered here; ``semcityloc.baselines`` registers its own
methods when it is imported (the benchmark imports it), so this module knows nothing of them.

A method localizes a query record (``QueryRecord``): the camera, the prior in the map model's LOCAL
frame, the query mask and optional depth; simulated queries also carry their true pose, which only
baselines that simulate their own input (the wireframe's edge map) read.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

from semcityloc.citymodel.model import CityModel
from semcityloc.errors import BenchmarkError, unknown_choice
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

    def localize(self, q: QueryRecord) -> LocalizationResult: ...


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


_REGISTRY: dict[str, MethodFactory] = {}
# Methods that search the map model as it is, without the localizer's eaves (``register_method``).
_AS_IS: set[str] = set()

# Order of the paper's main table: the full method first, then the ablations.
ABLATIONS: tuple[str, ...] = tuple(ABLATION_FLAGS)


def register_method(name: str, factory: MethodFactory, replace: bool = False, map_eaves: bool = True) -> None:
    """Add a method: ``factory(name, map_model, localizer_config) -> Method``. ``map_eaves``: whether it
    searches the localizer config's map (the model with ``map_eaves_m`` of eaves, ``localizer_scene``)
    rather than the model as it is (the wireframe baseline, whose edges are the model's own)."""
    if not name or not isinstance(name, str):
        raise BenchmarkError(f"a method name must be a non-empty string, got {name!r}")
    if name in _REGISTRY and not replace:
        raise BenchmarkError(f"method {name!r} is already registered")
    _REGISTRY[name] = factory
    (_AS_IS.discard if map_eaves else _AS_IS.add)(name)


def searched_map(name: str, config: LocalizerConfig) -> dict[str, Any]:
    """The map method ``name`` searches with ``config``, as a run records it (``run.json``'s
    ``searched_map``) and its drawings read it (``benchmark.found_map``): ``eaves_m``, the eaves on its
    pitched roofs, and ``flat_roofs``, ``config.map_eaves_flat_roofs`` (``"off"`` without eaves)."""
    check_method(name)
    if name in _AS_IS or not config.map_eaves_m > 0.0:
        return {"eaves_m": 0.0, "flat_roofs": "off"}
    return {"eaves_m": float(config.map_eaves_m), "flat_roofs": str(config.map_eaves_flat_roofs)}


def available_methods() -> tuple[str, ...]:
    """The method names registered so far, in registration order.

    SemCityLoc and its ablations are always there; the baselines only once ``semcityloc.baselines`` has been
    imported (it registers them as a side effect), which is why the benchmark layer imports it before listing
    or checking methods.
    """
    return tuple(_REGISTRY)


def check_method(name: str) -> str:
    """``name`` if it is a registered method, else a ``BenchmarkError`` naming the known ones.

    Called when a run is described (its spec made), so a typo in ``--method`` is refused before any work.
    """
    if name not in _REGISTRY:
        raise unknown_choice("method", name, _REGISTRY, BenchmarkError)
    return name


def method_factory(name: str) -> MethodFactory:
    """The factory registered as ``name``."""
    return _REGISTRY[check_method(name)]


def get_method(name: str, map_model: CityModel, config: LocalizerConfig | None = None) -> Method:
    """Build method ``name`` for ``map_model`` (``config``: the localizer preset, default ``default``)."""
    check_method(name)
    return _REGISTRY[name](
        name, map_model, config if config is not None else LocalizerConfig.preset("default")
    )


for _name in ABLATIONS:
    register_method(_name, LocalizerMethod)
