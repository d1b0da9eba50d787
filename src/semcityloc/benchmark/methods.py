"""The one table of methods by name: SemCityLoc, its ablations and the baselines.

Why here: SemCityLoc and its ablations live in ``localization`` (``localization.methods.LOCALIZER_METHODS``),
the baselines one layer above (``baselines.methods.BASELINE_METHODS``). The benchmark layer sits above both,
so it can list them all without either importing the other and without a table that fills itself as a side
effect of an import (where a name meant a method or not depending on what had been imported before).
Every caller that names a method by string asks this module: the specs' checks and ``run.json``'s
``searched_map`` (``benchmark.spec``, ``dataset_source``, ``photo_spec``), the run loop (``benchmark.run``),
the drawings of a run's maps (``benchmark.found_map``), the warm-up (``benchmark.warmup``) and the CLI's
``--method`` choices.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType
from typing import Any

from semcityloc.baselines.methods import BASELINE_METHODS
from semcityloc.citymodel.model import CityModel
from semcityloc.errors import BenchmarkError, unknown_choice
from semcityloc.localization.config import LocalizerConfig
from semcityloc.localization.methods import LOCALIZER_METHODS, Method, MethodEntry, MethodFactory

# Every method by name, in the order of the paper's tables: SemCityLoc, its ablations, the baselines.
METHODS: Mapping[str, MethodEntry] = MappingProxyType({**LOCALIZER_METHODS, **BASELINE_METHODS})


def available_methods() -> tuple[str, ...]:
    """The names of every method (``METHODS``), in table order."""
    return tuple(METHODS)


def check_method(name: str) -> str:
    """``name`` when it names a method, else ``BenchmarkError`` listing the known ones."""
    if name not in METHODS:
        raise unknown_choice("method", name, METHODS, BenchmarkError)
    return name


def method_factory(name: str) -> MethodFactory:
    """The factory of method ``name``: ``factory(name, map_model, localizer_config) -> Method``."""
    return METHODS[check_method(name)].factory


def get_method(name: str, map_model: CityModel, config: LocalizerConfig | None = None) -> Method:
    """Build method ``name`` for ``map_model`` (``config``: the localizer preset, default ``default``)."""
    config = config if config is not None else LocalizerConfig.preset("default")
    return method_factory(name)(name, map_model, config)


def searched_map(name: str, config: LocalizerConfig) -> dict[str, Any]:
    """The map method ``name`` searches with ``config`` (``MethodEntry.searched_map``): the model with the
    localizer's eaves, or as it is for the wireframe baseline."""
    return METHODS[check_method(name)].searched_map(config)
