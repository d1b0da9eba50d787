"""The CRS of a CityGML file as its reader meets it, and the one metric frame its coordinates go to.

Why a module of its own: a CityGML file names its CRS wherever it likes (the root or a building's
``gml:Envelope``, any geometry's ``srsName``), while the reader (``citymodel.citygml``) streams city objects
and must convert the first building's polygons before it has seen the rest. ``CRSChoice`` keeps what was
met so far and decides once, at the first building with polygons:

- the source CRS: ``crs_override``, else the file's first ``srsName`` (a later different one only warns);
  none at all: coordinates are used as they are, with a warning;
- the target: ``target_crs``, else the source, else (geographic source) the UTM zone of the data
  (``MetricFrame``), located by the first Envelope's corners when that Envelope holds the first building,
  else (a stale Envelope, e.g. ``0 0 / 1 1`` left by a tool) by the building, with a warning.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyproj

from semcityloc.citymodel.builder import usable_points
from semcityloc.citymodel.citygml_names import local_name
from semcityloc.citymodel.crs import (
    CRS_HINT,
    MetricFrame,
    check_degrees,
    named_by,
    overridden_warning,
    parse_crs_name,
    same_crs,
)
from semcityloc.citymodel.model import ParseStats, crs_label
from semcityloc.errors import CRSError


class CRSChoice:
    """The srsNames of one CityGML file (each new one appended to ``srs_names``; warnings into ``stats``),
    the Envelope's sample location, and the metric frame (``frame``, chosen by ``choose``; ``identity``:
    it leaves coordinates as they are)."""

    def __init__(
        self,
        path: Path,
        target_crs: pyproj.CRS | None,
        crs_override: str | None,
        stats: ParseStats,
        srs_names: list[str],
    ):
        self.path = path
        self.target_crs = target_crs
        self.crs_override = crs_override
        self.stats = stats
        self.srs_names = srs_names
        self.frame: MetricFrame | None = None
        self.identity = True
        self._srs_first: str | None = None
        self._srs_seen: set[str] = set()
        self._envelope_sample: np.ndarray | None = None

    def read_envelope_prop(self, prop) -> None:
        """``gml:boundedBy/gml:Envelope``: its srsName, and its corners as a sample location."""
        for env in prop:
            if env.tag.__class__ is not str or local_name(env.tag) != "Envelope":
                continue
            srs = env.get("srsName")
            if srs is not None:
                self.note_srs(srs)
            if self._envelope_sample is None:
                corners = [
                    c.text for c in env if c.tag.__class__ is str and local_name(c.tag).endswith("Corner")
                ]
                try:
                    pts = [np.array(t.split(), dtype=np.float64)[:2] for t in corners if t]
                except ValueError:
                    continue
                if len(pts) == 2 and all(len(p) == 2 for p in pts) and usable_points(np.stack(pts)).all():
                    self._envelope_sample = np.stack(pts)

    def note_srs(self, name: str) -> None:
        """Record an srsName met in the file; the first one names the CRS, a different later one warns."""
        if name in self._srs_seen:
            return
        self._srs_seen.add(name)
        self.srs_names.append(name)
        if self._srs_first is None:
            self._srs_first = name
        elif not _same_crs(name, self._srs_first):
            self.stats.warnings.append(
                f"srsName {name!r} differs from the file's first srsName {self._srs_first!r}, which is used "
                "for all coordinates"
            )

    def choose(self, exteriors: list[np.ndarray]) -> MetricFrame:
        """The metric frame, chosen at the first building with polygons (``exteriors``: their exterior
        rings in file coordinates) and kept for the rest of the file."""
        if self.frame is not None:
            return self.frame
        name = self.crs_override if self.crs_override is not None else self._srs_first
        if self.crs_override is not None and self._srs_first is not None:
            if (said := overridden_warning(self.crs_override, self._srs_first)) is not None:
                self.stats.warnings.append(said)
        source = None
        if name is None:
            self.stats.warnings.append(
                "the file names no CRS (srsName): coordinates are used as they are, in a local metric frame"
            )
            if self.target_crs is not None:
                self.stats.warnings.append(f"target_crs ignored: the source CRS is unknown ({CRS_HINT})")
        else:
            try:
                source = parse_crs_name(name)
            except CRSError as exc:
                hint = "" if self.crs_override is not None else f"; {CRS_HINT} to read the file anyway"
                raise CRSError(f"{self.path}: {exc}{hint}") from exc
        target = self.target_crs if source is not None else None
        said = named_by(self.crs_override, name, "the file's srsName")
        check_degrees(source, np.concatenate([e[:, :2] for e in exteriors]), str(self.path), said)
        frame = MetricFrame.for_source(source, self._zone_sample(exteriors), target)
        envelope = self._envelope_sample
        if target is None and envelope is not None and not _holds(envelope, exteriors):
            frame = self._frame_of_geometry(source, frame, exteriors)
        self.frame = frame
        self.identity = frame.target is None or (frame.target == frame.source and not frame.lat_first)
        return frame

    def _zone_sample(self, exteriors: list[np.ndarray]) -> np.ndarray:
        """The points that locate a geographic CRS's UTM zone: the Envelope's corners (the whole file's
        extent), else the first polygon read."""
        if self._envelope_sample is not None:
            return self._envelope_sample
        return exteriors[0][:, :2]

    def _frame_of_geometry(
        self, source: pyproj.CRS | None, frame: MetricFrame, exteriors: list[np.ndarray]
    ) -> MetricFrame:
        """The metric frame located by the first building's own coordinates when the Envelope does not hold
        them (a stale Envelope, e.g. 0 0 / 1 1 left by a tool); ``frame`` (the Envelope's) when both
        choose the same CRS, so that only a frame the Envelope got wrong changes, with a warning."""
        sample = np.concatenate([e[:, :2] for e in exteriors])
        ours = MetricFrame.for_source(source, sample, None)
        if ours.target == frame.target:
            return frame
        self.stats.warnings.append(
            f"the file's gml:Envelope does not hold its first building (a stale Envelope?): the UTM zone is "
            f"chosen from the building's coordinates ({crs_label(ours.target)}), not from the Envelope's "
            f"({crs_label(frame.target)})"
        )
        return ours


def _same_crs(a: str, b: str) -> bool:
    """Whether two srsName strings name the same CRS (``crs.same_crs``: spellings differ, EPSG:25833 vs its
    URN; the axis order counts); not when either cannot be read."""
    try:
        return same_crs(a, b)
    except CRSError:
        return False


def _holds(box: np.ndarray, exteriors: list[np.ndarray]) -> bool:
    """Whether the (2, 2) Envelope corners ``box`` hold every point of ``exteriors`` (file axis order,
    within 1 % of the box's size: Envelopes are often rounded)."""
    lo, hi = box.min(axis=0), box.max(axis=0)
    margin = 0.01 * (hi - lo) + 1e-9 * np.maximum(np.abs(lo), np.abs(hi))
    points = np.concatenate([e[:, :2] for e in exteriors])
    return bool(((points >= lo - margin) & (points <= hi + margin)).all())
