"""Registry of the localization methods the benchmark compares: SemCityLoc, its ablations, baselines.

Why a registry: the runner, the CLI and the report name methods by string (``--method no-depth``);
baselines added later (``lodloc-wireframe``, ``silhouette``) register a factory here and every tool
picks them up. A method is built once per process for one map and then localizes many queries.

``get_method(name, map_model, config)``: ``config`` is the localizer preset the run uses; SemCityLoc and
its ablations apply ``config.with_ablation(name)``. Queries carry their prior in the map model's LOCAL
frame, so methods call the localizer with ``prior_frame="local"``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Protocol

from semcityloc.citymodel.model import CityModel
from semcityloc.errors import ParameterError
from semcityloc.localization.config import LocalizerConfig
from semcityloc.localization.result import LocalizationResult

if TYPE_CHECKING:
    from semcityloc.benchmark.queries import BenchmarkQuery


class BenchmarkError(ParameterError):
    """A benchmark request that cannot run: unknown method or preset, bad option, unusable output folder."""


class Method(Protocol):
    """What the runner calls for every query."""

    name: str

    def localize(self, q: BenchmarkQuery) -> LocalizationResult: ...


MethodFactory = Callable[[str, CityModel, LocalizerConfig], Method]


class LocalizerMethod:
    """SemCityLoc (``semcityloc``) or one of its ablations on a ``Localizer`` built once."""

    def __init__(self, name: str, map_model: CityModel, config: LocalizerConfig):
        from semcityloc.localization.localize import Localizer

        self.name = name
        self.config = config.with_ablation(name)
        self.localizer = Localizer(map_model, self.config)

    def localize(self, q: BenchmarkQuery) -> LocalizationResult:
        return self.localizer.localize(q.camera, q.prior_pose, q.labels, q.depth, prior_frame="local")


_REGISTRY: dict[str, MethodFactory] = {}

# Order of the paper's main table: the full method first, then the ablations, then baselines.
ABLATIONS = ("semcityloc", "no-coarse", "no-refine", "no-depth")


def register_method(name: str, factory: MethodFactory, replace: bool = False) -> None:
    """Add a method: ``factory(name, map_model, localizer_config) -> Method``."""
    if not name or not isinstance(name, str):
        raise BenchmarkError(f"a method name must be a non-empty string, got {name!r}")
    if name in _REGISTRY and not replace:
        raise BenchmarkError(f"method {name!r} is already registered")
    _REGISTRY[name] = factory


def available_methods() -> tuple[str, ...]:
    return tuple(_REGISTRY)


def check_method(name: str) -> str:
    if name not in _REGISTRY:
        raise BenchmarkError(f"unknown method {name!r}; known: {', '.join(_REGISTRY)}")
    return name


def get_method(name: str, map_model: CityModel, config: LocalizerConfig | None = None) -> Method:
    """Build method ``name`` for ``map_model`` (``config``: the localizer preset, default ``default``)."""
    check_method(name)
    return _REGISTRY[name](
        name, map_model, config if config is not None else LocalizerConfig.preset("default")
    )


for _name in ABLATIONS:
    register_method(_name, LocalizerMethod)


def _baseline_factory(name: str, map_model: CityModel, config: LocalizerConfig) -> Method:
    """The baselines of ``semcityloc.baselines`` (imported only when one is asked for)."""
    from semcityloc.baselines.methods import make_baseline_method

    return make_baseline_method(name, map_model, config)


for _name in ("silhouette", "lodloc-wireframe"):  # = semcityloc.baselines.methods.BASELINES
    register_method(_name, _baseline_factory)
