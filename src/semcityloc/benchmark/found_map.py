"""The map a pose was searched and found on, for the drawings of the map at a pose.

Why: a localizer does not search the model as it is. It adds ``map_eaves_m`` (0.5 m by default) of eaves
to its pitched roofs, since that is how far real roofs overhang the LoD2 walls (``citymodel.eaves``), and with
``map_eaves_flat_roofs="auto"`` (the default) it may take a view's pose from a second map, the one with
eaves on its flat roofs too (``Refiner.look_with_flat_eaves``; with ``"on"`` every pose is found there).
A drawing of the model as it is at such a pose shows roof outlines the pose was not scored against: a hit
looks off by the eaves' width. So the report's figures, its query browser and a photo run's overlays draw
every pose (the truth, the prior, the estimate) on the map the run searched (``searched``), and an
estimate found on the flat-eaves map on that one, built by the localizer's own construction
(``map_scenes.flat_eaves_scene``, once per run, on the first estimate that needs it); their captions name
it (``FLAT_EAVES_MAP``).

Which map a run searched comes from its ``run.json``: ``searched_map`` (``benchmark.methods
.searched_map``: the wireframe baseline searches the model as it is), or for a run from before that key
its method and ``localizer`` config. Which map a pose was found on comes from what the result recorded,
``search["flat_roof_eaves"]``: live in a run, saved in a details file's ``meta["flat_roof_eaves"]`` and a
``results.csv`` row's ``flat_roof_eaves_used``, with the run's ``map_eaves_flat_roofs``
(``map_scenes.found_on_flat_eaves``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from semcityloc.benchmark.methods import searched_map
from semcityloc.citymodel.model import CityModel
from semcityloc.errors import BenchmarkError
from semcityloc.localization.config import LocalizerConfig
from semcityloc.localization.map_scenes import eaves_scene, flat_eaves_scene, found_on_flat_eaves
from semcityloc.render import Renderer

FLAT_EAVES_MAP = "the map with eaves on its flat roofs"


def row_look(row: dict[str, str]) -> dict | None:
    """A ``results.csv`` row's record of the flat-eaves look (``flat_roof_eaves_used``) in the form of
    ``search["flat_roof_eaves"]``: None when it made none (or the run predates the column)."""
    used = row.get("flat_roof_eaves_used", "")
    return None if used == "" else {"used": used == "1"}


def run_searched_map(config: dict) -> dict:
    """``{"eaves_m", "flat_roofs"}`` of the map a run searched, from its ``run.json``: its
    ``searched_map``; for a run from before that key, its method's with its ``localizer`` config; none
    for a run from before the map's eaves (its poses were all searched on the model as it is)."""
    recorded = config.get("searched_map")
    if isinstance(recorded, dict):
        return recorded
    localizer = config.get("localizer") or {}
    flat_roofs = localizer.get("map_eaves_flat_roofs", "off")
    if isinstance(flat_roofs, bool):  # the field's form before stop 46
        flat_roofs = "on" if flat_roofs else "off"
    try:
        cfg = LocalizerConfig(
            map_eaves_m=float(localizer.get("map_eaves_m") or 0.0), map_eaves_flat_roofs=str(flat_roofs)
        )
        return searched_map(str(config.get("method") or "semcityloc"), cfg)
    except (BenchmarkError, ValueError, TypeError):  # a method or value of other code: its localizer's
        return {"eaves_m": float(localizer.get("map_eaves_m") or 0.0), "flat_roofs": str(flat_roofs)}


@dataclass
class FoundMaps:
    """The renderers of a run's drawings: ``base`` draws its map model as it is; ``searched()`` the map
    the run searched (the model with ``eaves_m`` on its pitched roofs, on its flat roofs too when
    ``flat_roofs`` is ``"on"``): the truth's and the prior's; ``for_estimate`` the map an estimate was
    found on. ``eaves_m`` and ``flat_roofs``: the run's ``searched_map``."""

    model: CityModel
    base: Renderer
    eaves_m: float = 0.0
    flat_roofs: str = "off"
    _searched: Renderer | None = field(default=None, repr=False)
    _flat: Renderer | None = field(default=None, repr=False)
    _flat_built: bool = field(default=False, repr=False)

    @classmethod
    def of_run(cls, model: CityModel, renderer: Renderer, config: dict) -> FoundMaps:
        """The maps of a run from its ``run.json`` (``run_searched_map``)."""
        searched = run_searched_map(config)
        return cls(model, renderer, float(searched.get("eaves_m") or 0.0), str(searched.get("flat_roofs")))

    @classmethod
    def of_method(
        cls, model: CityModel, renderer: Renderer, method: str, config: LocalizerConfig
    ) -> FoundMaps:
        """The maps of method ``method`` run with ``config`` (``benchmark.methods.searched_map``)."""
        searched = searched_map(method, config)
        return cls(model, renderer, searched["eaves_m"], searched["flat_roofs"])

    def searched(self) -> Renderer:
        """The renderer of the map the run searched, built on first use: ``base`` when its eaves move no
        roof. The same triangles as the localizer's ``localizer_scene`` (``map_scenes.eaves_scene``)."""
        if self._searched is None:
            scene = None
            if self.eaves_m > 0:
                scene = eaves_scene(self.base.scene, self.model, self.eaves_m, self.flat_roofs == "on")
            self._searched = self.base if scene is None else self.base.with_scene(scene)
        return self._searched

    def flat(self) -> Renderer | None:
        """The renderer of the map with eaves on its flat roofs too, built on first use; None when the
        run's eaves move no roof (0 m)."""
        if not self._flat_built:
            scene = flat_eaves_scene(self.base.scene, self.model, self.eaves_m) if self.eaves_m > 0 else None
            self._flat = None if scene is None else self.base.with_scene(scene)
            self._flat_built = True
        return self._flat

    def for_estimate(self, look: dict | None) -> tuple[Renderer, str | None]:
        """(renderer, caption) of the map an estimate was found on, given the result's record of the
        flat-eaves look (``search["flat_roof_eaves"]`` or a saved copy; None: no look): the flat-eaves map
        and ``FLAT_EAVES_MAP`` where the pose was found there, else ``searched()`` and None."""
        if found_on_flat_eaves(self.flat_roofs, look):
            flat = self.flat()
            if flat is not None:
                return flat, FLAT_EAVES_MAP
        return self.searched(), None
