"""The generated buildings written as a CityGML 2.0 file, one LoD per file (``write_citygml``).

Why not in ``citymodel.export``: that writes a ``CityModel`` mesh (PLY, OBJ, npz); this writes the
generator's semantic polygons (``generator_surfaces.Surface``) with their building attributes (roof type,
measured height, storeys) in the structure of state LoD products. The file is byte-identical for the same
footprints: lxml, ids numbered per building, every coordinate printed with three decimals.

- LoD1: each building's polygons inline in a ``bldg:lod1Solid`` WITHOUT semantics, as real LoD1 products
  are: readers classify those faces by their normals;
- LoD2: ``bldg:boundedBy`` Roof/Wall/GroundSurface features (one polygon each) and a ``bldg:lod2Solid``
  whose surface members xlink (``xlink:href="#id"``) to those polygons, as state LoD2 products do;
- LoD3: the same features, each wall with its ``bldg:opening`` Window and Door features, and a
  ``bldg:lod3Solid`` that xlinks the walls, roofs, ground and openings (a closed shell).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from lxml import etree

from semcityloc.citymodel.crs import metric_crs
from semcityloc.citymodel.generator_footprints import DEFAULT_CRS, Footprint, generated_crs_what
from semcityloc.citymodel.generator_surfaces import Surface, check_lod, city_surfaces
from semcityloc.errors import ParameterError

ROOF_TYPE_CODES = {"flat": "1000", "mono": "1010", "gable": "1030", "hip": "1040"}  # AdV roofType codes
ROOF_TYPE_CODESPACE = "http://www.sig3d.org/codelists/citygml/2.0/building/2.0/_AbstractBuilding_roofType.xml"

CORE_NS = "http://www.opengis.net/citygml/2.0"
BLDG_NS = "http://www.opengis.net/citygml/building/2.0"
GML_NS = "http://www.opengis.net/gml"
XLINK_NS = "http://www.w3.org/1999/xlink"
XSI_NS = "http://www.w3.org/2001/XMLSchema-instance"
SCHEMA_LOCATION = (
    "http://www.opengis.net/citygml/2.0 http://schemas.opengis.net/citygml/2.0/cityGMLBase.xsd "
    "http://www.opengis.net/citygml/building/2.0 http://schemas.opengis.net/citygml/building/2.0/building.xsd"
)


def srs_name(crs: str) -> str:
    """OGC URN for a CRS string (any of ``crs.parse_crs_name``'s forms) with an EPSG code: ``EPSG:25832``
    -> ``urn:ogc:def:crs:EPSG::25832``; the string as given otherwise. Refused unless projected
    (``crs.metric_crs``)."""
    parsed = metric_crs(crs, generated_crs_what(crs))
    auth = parsed.to_authority(min_confidence=90)
    if auth and auth[0] == "EPSG":
        return f"urn:ogc:def:crs:EPSG::{auth[1]}"
    return crs.strip()


def _q3(v: float) -> str:
    return f"{v:.3f}"


def _pos_list(ring: np.ndarray) -> str:
    closed = np.vstack([ring, ring[:1]])
    return " ".join(_q3(v) for v in closed.ravel())


class _Writer:
    """Builds one CityGML 2.0 document with lxml (ids unique per file)."""

    def __init__(self, srs: str, name: str):
        self.srs = srs
        nsmap = {None: CORE_NS, "bldg": BLDG_NS, "gml": GML_NS, "xlink": XLINK_NS, "xsi": XSI_NS}
        self.root = etree.Element(f"{{{CORE_NS}}}CityModel", nsmap=nsmap)
        self.root.set(f"{{{XSI_NS}}}schemaLocation", SCHEMA_LOCATION)
        etree.SubElement(self.root, f"{{{GML_NS}}}name").text = name
        self.root_env = etree.SubElement(self.root, f"{{{GML_NS}}}boundedBy")
        self.lo = np.full(3, np.inf)
        self.hi = np.full(3, -np.inf)

    def el(self, parent, ns: str, tag: str, **attrs) -> etree._Element:
        """A child element ``tag`` in namespace ``ns`` with the given attributes."""
        e = etree.SubElement(parent, f"{{{ns}}}{tag}")
        for k, v in attrs.items():
            e.set(k, v)
        return e

    def envelope(self, parent, lo: np.ndarray, hi: np.ndarray) -> None:
        """A 3D ``gml:Envelope`` of corners ``lo``, ``hi`` in the file's srsName."""
        env = self.el(parent, GML_NS, "Envelope", srsName=self.srs, srsDimension="3")
        self.el(env, GML_NS, "lowerCorner").text = " ".join(_q3(v) for v in lo)
        self.el(env, GML_NS, "upperCorner").text = " ".join(_q3(v) for v in hi)

    def polygon(self, parent, pid: str, s: Surface) -> None:
        """A ``gml:Polygon`` with id ``pid``: exterior and interior rings as 3D posLists."""
        poly = self.el(parent, GML_NS, "Polygon", **{f"{{{GML_NS}}}id": pid})
        ring = self.el(self.el(poly, GML_NS, "exterior"), GML_NS, "LinearRing")
        self.el(ring, GML_NS, "posList", srsDimension="3").text = _pos_list(s.exterior)
        for hole in s.interiors:
            ring = self.el(self.el(poly, GML_NS, "interior"), GML_NS, "LinearRing")
            self.el(ring, GML_NS, "posList", srsDimension="3").text = _pos_list(hole)

    def multi_surface(self, parent, lod: int, pid: str, s: Surface) -> None:
        """The surface as an ``lodNMultiSurface`` of one polygon (a boundary surface's or an opening's)."""
        ms = self.el(self.el(parent, BLDG_NS, f"lod{lod}MultiSurface"), GML_NS, "MultiSurface")
        self.polygon(self.el(ms, GML_NS, "surfaceMember"), pid, s)

    def solid(self, parent, lod: int, bid: str) -> etree._Element:
        """An ``lodNSolid`` of building ``bid``; returns its exterior shell for surface members."""
        solid = self.el(
            self.el(parent, BLDG_NS, f"lod{lod}Solid"), GML_NS, "Solid", **{f"{{{GML_NS}}}id": f"{bid}_solid"}
        )
        return self.el(
            self.el(solid, GML_NS, "exterior"),
            GML_NS,
            "CompositeSurface",
            **{f"{{{GML_NS}}}id": f"{bid}_shell"},
        )

    def xlink(self, shell, pid: str) -> None:
        """A shell member pointing at polygon ``pid``: the LoD2 solid shares the boundary surfaces'."""
        self.el(shell, GML_NS, "surfaceMember", **{f"{{{XLINK_NS}}}href": f"#{pid}"})

    def building(self, fp: Footprint, lod: int, surfaces: list[Surface]) -> None:
        """One Building at ``lod``: attributes, then LoD1 inline polygons or classed surfaces."""
        member = self.el(self.root, CORE_NS, "cityObjectMember")
        b = self.el(member, BLDG_NS, "Building", **{f"{{{GML_NS}}}id": fp.id})
        pts = np.concatenate([s.exterior for s in surfaces])
        lo, hi = pts.min(0), pts.max(0)
        self.lo, self.hi = np.minimum(self.lo, lo), np.maximum(self.hi, hi)
        self.envelope(self.el(b, GML_NS, "boundedBy"), lo, hi)
        self.el(b, BLDG_NS, "roofType", codeSpace=ROOF_TYPE_CODESPACE).text = ROOF_TYPE_CODES[fp.roof_type]
        self.el(b, BLDG_NS, "measuredHeight", uom="m").text = _q3(fp.height)
        self.el(b, BLDG_NS, "storeysAboveGround").text = str(fp.storeys)
        if lod == 1:  # inline polygons, no semantics (as real LoD1 products)
            shell = self.solid(b, 1, fp.id)
            for n, s in enumerate(surfaces):
                self.polygon(self.el(shell, GML_NS, "surfaceMember"), f"{fp.id}_p{n:03d}", s)
            return
        shell = self.solid(b, 2, fp.id) if lod == 2 else None
        solid_members: list[str] = []
        n_open = 0
        for n, s in enumerate(surfaces):
            pid = f"{fp.id}_p{n:03d}"
            solid_members.append(pid)
            feature = self.el(
                self.el(b, BLDG_NS, "boundedBy"), BLDG_NS, s.kind, **{f"{{{GML_NS}}}id": f"{fp.id}_s{n:03d}"}
            )
            self.multi_surface(feature, lod, pid, s)
            for o in s.openings:
                oid = f"{fp.id}_{'w' if o.kind == 'Window' else 'd'}{n_open:04d}"
                opening = self.el(
                    self.el(feature, BLDG_NS, "opening"), BLDG_NS, o.kind, **{f"{{{GML_NS}}}id": oid}
                )
                self.multi_surface(opening, lod, f"{oid}_p", o)
                solid_members.append(f"{oid}_p")
                n_open += 1
        if shell is None:
            shell = self.solid(b, 3, fp.id)  # lod3Solid comes after boundedBy in the 2.0 schema
        for pid in solid_members:
            self.xlink(shell, pid)

    def write(self, path: Path) -> Path:
        """Write the document to ``path`` atomically (through a .tmp), root Envelope filled in."""
        self.envelope(self.root_env, self.lo, self.hi)
        tmp = path.with_name(path.name + ".tmp")
        etree.ElementTree(self.root).write(
            str(tmp), xml_declaration=True, encoding="UTF-8", pretty_print=True
        )
        tmp.replace(path)
        return path


def write_citygml(
    footprints: list[Footprint], lod: int, path: str | Path, crs: str = DEFAULT_CRS, name: str = ""
) -> Path:
    """Write the buildings at one LoD as a CityGML 2.0 file."""
    lod = check_lod(lod)
    if not footprints:
        raise ParameterError("no footprints to write")
    writer = _Writer(srs_name(crs), name or f"semcityloc generated district LoD{lod}")
    for fp, surfaces in city_surfaces(footprints, lod):
        writer.building(fp, lod, surfaces)
    return writer.write(Path(path))
