"""Where a run's queries come from: the ``QuerySource`` protocol and the simulated source.

Why: the run loop (``benchmark.run.run_queries``) is the same whatever makes the queries — the query
simulator over a city model (``SimulatedSource``), a LoD-Loc data set folder
(``benchmark.dataset_source.DatasetSource``), later a COLMAP model or a folder of users' photos. A source
has ``len()`` and ``query(i)``; queries and poses are in its ``map_model``'s LOCAL frame.

A source is built in the parent process and pickled to the workers with its models; anything heavy it
builds from them (a simulator, a renderer) is built lazily in each process and never pickled.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

from semcityloc.benchmark.queries import BenchmarkQuery, QueryConfig, QuerySimulator
from semcityloc.citymodel.model import CityModel
from semcityloc.citymodel.tiles import TileStore
from semcityloc.localization.methods import Method
from semcityloc.localization.result import LocalizationResult

SimulatorFactory = Callable[[CityModel, QueryConfig, "CityModel | None"], Any]


class QuerySource(Protocol):
    """What the run loop needs of a source of queries."""

    map_model: CityModel  # the model methods localize against; queries are in its local frame

    def __len__(self) -> int: ...

    def query(self, index: int) -> BenchmarkQuery:
        """Query ``index`` (camera, prior, labels, depth, truth), made when the loop needs it."""

    def has_truth(self, index: int) -> bool:
        """Does query ``index`` have a true pose, known without making the query (a query that could not be
        made is then a miss of the recall: ``results.failed_row``)?"""

    def prepare(self, method: Method) -> None:
        """Give ``method`` what it needs of this source before the first query (may do nothing)."""

    def save_estimate(self, out_dir: Path, q: BenchmarkQuery, result: LocalizationResult) -> None:
        """Keep the estimate of a finished query beside the rows (may do nothing)."""


class SimulatedSource:
    """Queries made by the simulator (``benchmark.queries.QuerySimulator``) over a map and its reality.

    ``reality_model``: what the simulated drone sees (in the map's local frame); ``simulator_factory``
    (default ``QuerySimulator``) must be picklable by reference for ``workers > 1``; ``tile_store``: when
    the map is a tile store (``citymodel.tiles``), the methods load their parts of it per query
    (``localization.tiled``) while the simulator sees the whole (merged) city.
    """

    def __init__(
        self,
        map_model: CityModel,
        reality_model: CityModel,
        query_config: QueryConfig,
        simulator_factory: SimulatorFactory | None = None,
        tile_store: TileStore | None = None,
    ):
        self.map_model = map_model
        self.tile_store = tile_store
        self.reality_model = reality_model
        self.query_config = query_config
        self.simulator_factory = simulator_factory or QuerySimulator
        self._simulator = None

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_simulator"] = None  # rebuilt in each process
        return state

    @property
    def simulator(self):
        """The query simulator, made on first use (so a source pickles small for workers)."""
        if self._simulator is None:
            self._simulator = self.simulator_factory(self.map_model, self.query_config, self.reality_model)
        return self._simulator

    def __len__(self) -> int:
        return int(self.query_config.queries)

    def has_truth(self, index: int) -> bool:
        """Every simulated query has a true pose."""
        return True

    def query(self, index: int) -> BenchmarkQuery:
        """Query ``index`` as the simulator makes it (deterministic per index and seed)."""
        return self.simulator.query(index)

    def prepare(self, method: Method) -> None:
        """Give a baseline that simulates its own input the perturbed reality the labels show."""
        # Baselines that simulate their own query input (the wireframe's edge map) draw it from the same
        # perturbed reality the query labels come from, not from the exact map.
        attach = getattr(method, "attach_reality", None)
        reality = getattr(self.simulator, "reality", None)
        if attach is not None and reality is not None:
            attach(reality.model, reality.renderer.scene)

    def save_estimate(self, out_dir: Path, q: BenchmarkQuery, result: LocalizationResult) -> None:
        """Nothing kept: a simulated query's estimate is in its row and details."""
        return None
