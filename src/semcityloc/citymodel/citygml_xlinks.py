"""CityGML XLinks (``xlink:href="#id"``) resolved within a building, against earlier ones and later ones.

Why a module of its own: the reader streams one city object at a time, yet an XLink may point at a surface
of the same building, of an earlier one, or of one still to come. ``XLinkResolver`` keeps what that needs
across objects: a bounded cache of earlier objects' surfaces by gml:id (``XLINK_CACHE_IDS``, oldest dropped
first, so memory stays bounded on a 1 GB tile) and the references still waiting for their target. A
reference takes the target's polygons with the referring element's part, and its LoD and class where it
states them (else the target's); ``orientation="-"`` reverses them. What never resolves is counted by the
reader in ``stats.unresolved_xlinks``.
"""

from __future__ import annotations

from collections import OrderedDict

from semcityloc.citymodel.citygml_records import CityGMLReport, SurfaceRecord, SurfaceRef
from semcityloc.citymodel.citygml_walk import WalkedBuilding

# Cross-object XLink cache: surfaces (by gml:id) of earlier city objects kept for later references.
XLINK_CACHE_IDS = 100_000


def expand(ref: SurfaceRef, targets: list[SurfaceRecord]) -> list[SurfaceRecord]:
    """The target polygons as the referring element has them: its part, its LoD and class where it states
    them, reversed under ``orientation="-"``, marked as reached through an XLink."""
    out = []
    for r in targets:
        ext, holes = r.exterior, r.interiors
        if ref.flip:
            ext, holes = ext[::-1], [h[::-1] for h in holes]
        out.append(
            SurfaceRecord(
                ref.part,
                r.lod if ref.lod is None else ref.lod,
                r.semantic if ref.semantic is None else ref.semantic,
                ext,
                holes,
                r.gml_id,
                True,
            )
        )
    return out


class XLinkResolver:
    """The XLinks of one file, building by building: ``resolve`` a building's own references, ``register``
    its surfaces for later ones (and for earlier ones still waiting); counts go to ``report``."""

    def __init__(self, report: CityGMLReport):
        self.report = report
        self._cache: OrderedDict[str, list[SurfaceRecord]] = OrderedDict()
        self._pending: dict[str, list[tuple[str, SurfaceRef]]] = {}

    def resolve(self, building_id: str, walked: WalkedBuilding) -> tuple[list[SurfaceRecord], bool]:
        """The polygons the building's references reach (within it, else in the cache) and whether any
        reference is left waiting for a later object."""
        recs = walked.records
        resolved: list[SurfaceRecord] = []
        waiting: list[SurfaceRef] = []
        for ref in walked.refs:
            span = walked.ids.get(ref.target)
            if span is not None:
                resolved += expand(ref, recs[span[0] : span[1]])
                self.report.xlinks_resolved += 1
                continue
            cached = self._cache.get(ref.target)
            if cached is not None:
                resolved += expand(ref, cached)
                self.report.xlinks_resolved += 1
                self.report.xlinks_cross_object += 1
                continue
            waiting.append(ref)
        for ref in waiting:
            self._pending.setdefault(ref.target, []).append((building_id, ref))
        return resolved, bool(waiting)

    def register(self, walked: WalkedBuilding) -> list[tuple[str, list[SurfaceRecord]]]:
        """Offer the building's surfaces to earlier forward references (returned as (their building id, the
        polygons they reach now), in order) and to later objects (the bounded cache)."""
        late: list[tuple[str, list[SurfaceRecord]]] = []
        recs = walked.records
        for gid, (a, b) in walked.ids.items():
            targets = recs[a:b]
            waiting = self._pending.pop(gid, None) if self._pending else None
            if waiting:
                for building_id, ref in waiting:
                    self.report.xlinks_resolved += 1
                    self.report.xlinks_cross_object += 1
                    late.append((building_id, expand(ref, targets)))
            self._cache[gid] = targets
            self._cache.move_to_end(gid)
        while len(self._cache) > XLINK_CACHE_IDS:
            self._cache.popitem(last=False)
        return late

    def unresolved(self) -> int:
        """How many references are still waiting (at the end of the file: never resolved); forgets them."""
        n = sum(len(v) for v in self._pending.values())
        self._pending.clear()
        return n
