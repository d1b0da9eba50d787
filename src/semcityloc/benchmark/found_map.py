"""The map a pose was found on, for the drawings of the map at an estimate.

Why: with ``map_eaves_flat_roofs="auto"`` (the default) the localizer may take a view's pose from a second
map, the map with eaves on its flat roofs too (``Localizer._look_with_flat_eaves``; with ``"on"`` every
pose is found there). A drawing of the plain model at such an estimate shows roof outlines the pose was
not scored against: a hit looks off by the eaves' width. So the report's figures, its query browser and a
photo run's overlays draw an estimate found there on that map, built by the localizer's own construction
(``localize.flat_eaves_scene``, once per run, on the first estimate that needs it), and their captions
name it (``FLAT_EAVES_MAP``). Everything else (the truth, the prior, estimates found on the plain map) is
drawn on the run's map as it is.

Which map a pose was found on comes from what the result recorded, ``search["flat_roof_eaves"]``: live
in a run, saved in a details file's ``meta["flat_roof_eaves"]`` and a ``results.csv`` row's
``flat_roof_eaves_used``, with the run's ``map_eaves_flat_roofs`` (``localize.found_on_flat_eaves``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from semcityloc.citymodel.model import CityModel
from semcityloc.localization.localize import flat_eaves_scene, found_on_flat_eaves
from semcityloc.render import Renderer

FLAT_EAVES_MAP = "the map with eaves on its flat roofs"


def row_look(row: dict[str, str]) -> dict | None:
    """A ``results.csv`` row's record of the flat-eaves look (``flat_roof_eaves_used``) in the form of
    ``search["flat_roof_eaves"]``: None when it made none (or the run predates the column)."""
    used = row.get("flat_roof_eaves_used", "")
    return None if used == "" else {"used": used == "1"}


@dataclass
class FoundMaps:
    """The renderers of a run's drawings: ``base`` draws its map model as it is; ``for_estimate`` the map
    an estimate was found on. ``eaves_m`` and ``flat_roofs``: the run's ``LocalizerConfig.map_eaves_m``
    and ``map_eaves_flat_roofs``."""

    model: CityModel
    base: Renderer
    eaves_m: float = 0.0
    flat_roofs: str = "off"
    _flat: Renderer | None = field(default=None, repr=False)
    _flat_built: bool = field(default=False, repr=False)

    @classmethod
    def of_run(cls, model: CityModel, renderer: Renderer, config: dict) -> FoundMaps:
        """The maps of a run from its ``run.json`` (``config["localizer"]``); a run from before the map's
        eaves has none (its poses were all found on the model as it is)."""
        localizer = config.get("localizer") or {}
        flat_roofs = localizer.get("map_eaves_flat_roofs", "off")
        if isinstance(flat_roofs, bool):  # the field's form before stop 46
            flat_roofs = "on" if flat_roofs else "off"
        return cls(model, renderer, float(localizer.get("map_eaves_m") or 0.0), str(flat_roofs))

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
        and ``FLAT_EAVES_MAP`` where the pose was found there, else ``base`` and None."""
        if found_on_flat_eaves(self.flat_roofs, look):
            flat = self.flat()
            if flat is not None:
                return flat, FLAT_EAVES_MAP
        return self.base, None
