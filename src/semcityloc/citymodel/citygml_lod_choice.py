"""Which LoD of a CityGML building is meshed, per building and BuildingPart, and each surface only once.

Why a module of its own: a CityGML building often holds the same surfaces at several LoDs (an LoD1 block, an
LoD2 solid, LoD3 with openings), and a polygon may be reached twice (a ``lod2Solid`` member that points into a
``RoofSurface``). ``citygml_lod`` checks the reader's ``lod`` argument before the file is opened;
``LodChoice`` then keeps, per part, either the asked LoD or (``lod=None``) the highest the part has, dropping
the building's own geometry when one of its parts is more detailed (the coarse shell would enclose the
parts); polygons reached twice are meshed once, the labelled, directly defined one first. Polygons that
arrive later through a forward XLink (``citygml_xlinks``) are judged by the choice made for their building.
"""

from __future__ import annotations

import operator
from pathlib import Path

from semcityloc.citymodel.citygml_records import CityGMLReport, SurfaceRecord
from semcityloc.citymodel.cityjson import lod_key
from semcityloc.errors import ParameterError


def citygml_lod(lod: object, path: Path | None = None) -> int | None:
    """The LoD the reader keeps for ``lod``: None (each building's highest) or a whole LoD 0 to 4, given as
    an int or in a form the CityJSON reader takes for it (``"2"``, ``"2.0"``, ``2.0``: ``lod_key``).

    CityGML's LoDs are whole numbers, so anything else (``"foo"``, ``-1``, ``7``, ``"2.2"``, ``True``) is a
    ``ParameterError`` naming the value, raised before the file is opened, rather than a ``TypeError`` from
    deep inside or an empty model.
    """
    if lod is None:
        return None
    value = lod
    if not isinstance(lod, bool):
        try:
            value = operator.index(lod)  # numpy integers too
        except TypeError:
            pass
    key = lod_key(value)
    if key is None or "." in key:
        where = f"{path}: " if path is not None else ""
        raise ParameterError(
            f"{where}LoD {lod!r} is not a CityGML LoD: give a whole number 0 to 4 (or no LoD for each "
            "building's highest)"
        )
    return int(key)


class LodChoice:
    """The LoD kept per part of every building of one file (``lod``: from ``citygml_lod``); duplicates are
    counted in ``report``."""

    def __init__(self, lod: int | None, report: CityGMLReport):
        self.lod = lod
        self.report = report
        # buildings with references still waiting: the LoDs chosen and the gml:ids already meshed
        self._late: dict[str, tuple[dict[int, int], set[str]]] = {}

    def building(self, building_id: str, recs: list[SurfaceRecord], waiting: bool) -> list[SurfaceRecord]:
        """The polygons of a building that are meshed (its own and those its references reached); ``waiting``:
        some references wait for a later object, so the choice is kept for what they bring."""
        for r in recs:  # a LoD reached only through references is present too (count: 0 polygons)
            self.report.lod_polygons.setdefault(r.lod, 0)
        best: dict[int, int] = {}
        for r in recs:
            if r.lod > best.get(r.part, -1):
                best[r.part] = r.lod
        if self.lod is not None:
            chosen = {p: self.lod for p in best}
        else:
            chosen = dict(best)
            parts_best = max((v for p, v in chosen.items() if p != 0), default=-1)
            if 0 in chosen and parts_best > chosen[0]:
                chosen[0] = -1  # the building's own coarser shell would enclose its detailed parts
        seen: set[str] = set()
        keep = self._select(recs, chosen, seen)
        if waiting:
            self._late[building_id] = (chosen, seen)
        return keep

    def late(self, building_id: str, recs: list[SurfaceRecord]) -> list[SurfaceRecord]:
        """The polygons a forward reference of ``building_id`` reached later that are meshed, by the choice
        made for that building (a part it did not have yet takes the LoD they bring)."""
        chosen, seen = self._late.get(building_id, ({}, set()))
        for r in recs:
            self.report.lod_polygons.setdefault(r.lod, 0)
            if self.lod is None:
                chosen.setdefault(r.part, r.lod)
            else:
                chosen[r.part] = self.lod
        return self._select(recs, chosen, seen)

    def _select(
        self, recs: list[SurfaceRecord], chosen: dict[int, int], seen: set[str]
    ) -> list[SurfaceRecord]:
        """Records of the chosen LoD per part, each gml:id once (labelled, directly defined ones first)."""
        selected = [r for r in recs if chosen.get(r.part, r.lod) == r.lod]
        selected.sort(key=lambda r: (r.semantic is None, r.via_xlink))
        keep = []
        for r in selected:
            if r.gml_id is not None:
                if r.gml_id in seen:
                    self.report.duplicate_polygons += 1
                    continue
                seen.add(r.gml_id)
            keep.append(r)
        return keep
