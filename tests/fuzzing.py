"""Fuzz targets of the readers and their structure-aware mutators (not a test module).

Used by ``test_fuzz_readers.py`` (a short, seeded slice in the suite) and ``fuzz_run.py`` (``make fuzz``:
>= 10,000 inputs per target, the table in ``docs/reliability.md``). Every target turns bytes into a file
(or a folder) and reads it with the library's reader; the outcome of one input is:

- ``typed``: the reader raised a ``SemCityLocError`` (a clear, typed answer to bad input);
- ``valid``: it returned a result;
- ``crash``: anything else (a traceback from deep inside numpy, lxml, struct, ...): a bug.

Seeds are small valid files made here (always present) and, when ``../shared/data`` is there, excerpts of
the real public files (each trimmed to a few buildings so that thousands of inputs run in minutes).
Mutations know the formats: numbers in coordinate lists become NaN / inf / 1e308 / garbage, XML elements
are deleted, duplicated or renamed, attributes (srsDimension, xlink:href, namespaces) changed, JSON nodes
replaced by values of other types, OBJ face indices pushed out of range, binary count fields overwritten,
images re-encoded with other modes, dtypes and shapes, DJI XMP fields given impossible values; on top of
the byte-level flips, truncations and splices.
"""

from __future__ import annotations

import copy
import io
import json
import random
import re
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, PngImagePlugin

from dji_photo import RTK_FIELDS, dji_jpeg, xmp_packet
from semcityloc.citymodel.citygml import read_citygml
from semcityloc.citymodel.cityjson import read_cityjson
from semcityloc.citymodel.export import export_model
from semcityloc.citymodel.generator import generate_city
from semcityloc.citymodel.obj import read_obj
from semcityloc.datasets.colmap import read_model, write_model
from semcityloc.datasets.dji_metadata import read_dji_metadata
from semcityloc.datasets.geotags import read_geotags_csv
from semcityloc.datasets.lodloc import read_split
from semcityloc.errors import SemCityLocError
from semcityloc.geometry.io import read_intrinsics, read_pose
from semcityloc.io.images import read_depth_file, read_mask_file, save_depth, save_labels_png
from test_cityjson import box_doc

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"

TYPED, VALID, CRASH = "typed", "valid", "crash"

WEIRD_NUMBERS = [
    "nan", "NaN", "inf", "-inf", "1e308", "-1e308", "1e309", "4.9e-324", "0", "-0", "", "1e99999", "0x1F",
    "1,5", "--1", "9" * 400, "1 2", "+", ".", "e5", "2147483648", "-2147483649", "18446744073709551616",
]  # fmt: skip
WEIRD_JSON = [None, -1, 0, 1e300, -1e300, float("nan"), float("inf"), "x", "", [], {}, [[]], [None],
              2**63, -(2**63), True, [0, 0], {"a": None}, "EPSG:999999", [[[[[[1]]]]]]]  # fmt: skip


# --------------------------------------------------------------------------------------------- mutators
def _bytes_mutation(rng: random.Random, data: bytes) -> bytes:
    """Flip, insert, delete, truncate, splice or overwrite a 4/8-byte field (counts, sizes, offsets)."""
    if not data:
        return bytes(rng.randrange(256) for _ in range(rng.randrange(1, 64)))
    b = bytearray(data)
    op = rng.randrange(7)
    i = rng.randrange(len(b))
    if op == 0:
        for _ in range(rng.randrange(1, 9)):
            b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
    elif op == 1:
        b[i:i] = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 16)))
    elif op == 2:
        del b[i : i + rng.randrange(1, 256)]
    elif op == 3:
        del b[i:]
    elif op == 4:
        j = rng.randrange(len(b))
        b[i:i] = b[j : j + rng.randrange(1, 512)]
    else:
        width = 4 if op == 5 else 8
        value = rng.choice([0, 1, 2**31 - 1, 2**32 - 1, 2**63 - 1, 2**64 - 1, rng.randrange(2**32)])
        b[i : i + width] = value.to_bytes(8, "little")[:width]
    return bytes(b)


_NUMBER = re.compile(rb"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


def _number_mutation(rng: random.Random, data: bytes) -> bytes:
    """Replace a few numbers (coordinates, indices, matrix entries) with weird ones."""
    spans = [m.span() for m in _NUMBER.finditer(data[:200_000])]
    if not spans:
        return _bytes_mutation(rng, data)
    out = bytearray(data)
    for a, b in sorted(rng.sample(spans, min(len(spans), rng.randrange(1, 6))), reverse=True):
        out[a:b] = rng.choice(WEIRD_NUMBERS).encode()
    return bytes(out)


def _line_mutation(rng: random.Random, data: bytes) -> bytes:
    """Delete, duplicate, swap or cut a line."""
    lines = data.split(b"\n")
    i, j = rng.randrange(len(lines)), rng.randrange(len(lines))
    op = rng.randrange(4)
    if op == 0:
        del lines[i]
    elif op == 1:
        lines.insert(i, lines[j])
    elif op == 2:
        lines[i], lines[j] = lines[j], lines[i]
    else:
        lines[i] = lines[i][: rng.randrange(len(lines[i]) + 1)]
    return b"\n".join(lines)


def text_mutation(rng: random.Random, data: bytes) -> bytes:
    return rng.choice([_number_mutation, _number_mutation, _line_mutation, _bytes_mutation])(rng, data)


_TAG = re.compile(rb"<([A-Za-z_][\w.-]*:)?([A-Za-z_][\w.-]*)[\s>/]")
XML_INSERTS = [
    b'<!DOCTYPE CityModel [<!ENTITY x "xx">]>',
    b'<!DOCTYPE CityModel SYSTEM "file:///etc/hostname">',
    b'<!DOCTYPE CityModel [<!ENTITY % p SYSTEM "file:///nonexistent"> %p;]>',
    b"&x;",
    b"<![CDATA[1 2 3]]>",
    b"<!-- -->",
    b'<xi:include xmlns:xi="http://www.w3.org/2001/XInclude" href="file:///etc/hostname" parse="text"/>',
]
XML_ATTRIBUTES = [
    (rb'srsDimension="\d+"', [b'srsDimension="2"', b'srsDimension="0"', b'srsDimension="-1"',
                              b'srsDimension="x"', b'srsDimension="99999999999"', b'srsDimension="4"']),
    (rb'srsName="[^"]*"', [b'srsName=""', b'srsName="EPSG:4326"', b'srsName="urn:ogc:def:crs:EPSG::999999"',
                           b'srsName="urn:adv:crs:nonsense"', b'srsName="EPSG:25832+5783"']),
    (rb'xlink:href="[^"]*"', [b'xlink:href=""', b'xlink:href="#"', b'xlink:href="#nope"',
                              b'xlink:href="http://example.com/x"', b'xlink:href="#B1"']),
    (rb"citygml/\d\.\d", [b"citygml/9.9", b"citygml/1.0", b"citygml/3.0", b"citygml/2.0"]),
    (rb'orientation="[^"]*"', [b'orientation="-"', b'orientation="+"', b'orientation="?"']),
]  # fmt: skip


def xml_mutation(rng: random.Random, data: bytes) -> bytes:
    """Element deletions, duplications and renames, attribute changes, DTDs and entities; or text ones."""
    op = rng.randrange(8)
    tags = [m for m in _TAG.finditer(data[:500_000])]
    if op == 0 and tags:  # delete an element (to the end of its first closing tag)
        m = rng.choice(tags)
        end = data.find(b"</" + (m.group(1) or b"") + m.group(2) + b">", m.start())
        if end > 0:
            return data[: m.start()] + data[end + len(m.group(2)) + len(m.group(1) or b"") + 3 :]
    if op == 1 and tags:  # duplicate an element
        m = rng.choice(tags)
        close = b"</" + (m.group(1) or b"") + m.group(2) + b">"
        end = data.find(close, m.start())
        if end > 0:
            end += len(close)
            return data[:end] + data[m.start() : end] + data[end:]
    if op == 2 and len(tags) > 1:  # rename every occurrence of one element name to another's
        a, b = rng.sample(tags, 2)
        return data.replace(a.group(2) + b">", b.group(2) + b">").replace(
            a.group(2) + b" ", b.group(2) + b" "
        )
    if op == 3:  # change an attribute
        pattern, values = rng.choice(XML_ATTRIBUTES)
        found = list(re.finditer(pattern, data[:500_000]))
        if found:
            m = rng.choice(found)
            return data[: m.start()] + rng.choice(values) + data[m.end() :]
    if op == 4:  # a DOCTYPE, entity, CDATA, comment or XInclude somewhere
        insert = rng.choice(XML_INSERTS)
        at = data.find(b"<", data.find(b"?>") + 1) if insert.startswith(b"<!DOCTYPE") else None
        at = at if at is not None and at >= 0 else rng.randrange(len(data) + 1)
        return data[:at] + insert + data[at:]
    return text_mutation(rng, data)


def _json_nodes(value, path=()):
    yield path, value
    if isinstance(value, dict):
        for k, v in value.items():
            yield from _json_nodes(v, (*path, k))
    elif isinstance(value, list):
        for i, v in enumerate(value[:50]):
            yield from _json_nodes(v, (*path, i))


def json_mutation(rng: random.Random, data: bytes) -> bytes:
    """Replace, delete or duplicate a node of the parsed document (keys, transform, vertices, boundaries,
    semantics); or a text mutation of the serialised JSON."""
    try:
        doc = json.loads(data)
    except (ValueError, UnicodeDecodeError):
        lines = data.split(b"\n")
        if len(lines) > 1 and rng.random() < 0.75:  # a CityJSONSeq stream: one of its lines mutated
            i = rng.randrange(len(lines))
            lines[i] = json_mutation(rng, lines[i])
            return b"\n".join(lines)
        return text_mutation(rng, data)
    if rng.random() < 0.25:
        return text_mutation(rng, data)
    for _ in range(rng.randrange(1, 4)):
        nodes = list(_json_nodes(doc))
        path, _ = rng.choice(nodes)
        if not path:
            continue
        parent = doc
        for key in path[:-1]:
            parent = parent[key]
        key = path[-1]
        op = rng.randrange(4)
        if op == 0 or (op == 1 and not isinstance(parent, dict)):
            parent[key] = copy.deepcopy(rng.choice(WEIRD_JSON))
        elif op == 1:
            del parent[key]
        elif op == 2 and isinstance(parent, list):
            parent.insert(key, parent[key])
        elif op == 3 and isinstance(parent[key], int | float) and not isinstance(parent[key], bool):
            parent[key] = rng.choice([parent[key] * 1000, -parent[key], parent[key] + 2**31, 10**7])
    return json.dumps(doc).encode()


def obj_mutation(rng: random.Random, data: bytes) -> bytes:
    """Face indices out of range, zero or negative, vertices with missing or extra numbers; or text ones."""
    lines = data.split(b"\n")
    faces = [i for i, ln in enumerate(lines) if ln.startswith(b"f ") and len(ln.split()) > 1]
    verts = [i for i, ln in enumerate(lines) if ln.startswith(b"v ")]
    op = rng.randrange(4)
    if op == 0 and faces:
        i = rng.choice(faces)
        idx = rng.choice([b"0", b"-1", b"-999999", b"99999999", b"1/2/3", b"1//", b"x", b"2147483648"])
        parts = lines[i].split()
        parts[rng.randrange(1, len(parts))] = idx
        lines[i] = b" ".join(parts)
    elif op == 1 and verts:
        i = rng.choice(verts)
        lines[i] = rng.choice([b"v 1 2", b"v", b"v 1 2 3 4 5 6 7", b"v nan nan nan", b"v 1e308 1e308 1e308"])
    elif op == 2:
        lines.insert(rng.randrange(len(lines) + 1), rng.choice([b"f 1 1 1", b"f 1 2", b"o", b"g", b"usemtl"]))
    else:
        return text_mutation(rng, data)
    return b"\n".join(lines)


def image_mutation(rng: random.Random, data: bytes) -> bytes:
    """A re-encoding of a random array (mode, dtype, shape, format: PNG / JPEG / TIFF / npy), or bytes."""
    if rng.random() < 0.5:
        return _bytes_mutation(rng, data)
    h, w = rng.choice([(1, 1), (0, 5), (48, 64), (3, 4), (64, 48)])
    kind = rng.randrange(6)
    arr = np.random.default_rng(rng.randrange(2**32)).integers(0, 256, (max(h, 1), w), dtype=np.uint8)
    buf = io.BytesIO()
    if kind == 0:
        dtype = rng.choice([np.uint8, np.int64, np.float32, np.float64, np.bool_, np.complex64, "U3"])
        shape = rng.choice([(h, w), (h, w, 3), (w,), (), (2, h, w)])
        values = np.zeros(shape, dtype=dtype)
        if values.dtype.kind == "f":
            values[...] = np.nan
        np.save(buf, values)
    elif kind == 1:
        Image.fromarray(arr, mode="L").save(buf, format=rng.choice(["PNG", "JPEG", "TIFF", "BMP", "GIF"]))
    elif kind == 2:
        Image.fromarray(np.stack([arr] * 3, -1), mode="RGB").save(buf, format="PNG")
    elif kind == 3:
        Image.fromarray(arr.astype(np.uint16) * 257).save(buf, format="PNG")
    elif kind == 4:
        Image.fromarray(arr.astype(np.float32)).save(buf, format="TIFF")
    else:
        img = Image.fromarray(arr, mode="P")
        info = PngImagePlugin.PngInfo()
        info.add_text("depth_unit_m", rng.choice(["nan", "-1", "1e308", "x", "0", "0.001"]))
        img.save(buf, format="PNG", pnginfo=info)
    return buf.getvalue()


DJI_FIELD_VALUES = [
    "",
    "nan",
    "inf",
    "+999.0",
    "-91",
    "+181",
    "1e308",
    "abc",
    "+48.1.2",
    "--5",
    "0x10",
    "9" * 300,
]


def dji_mutation(rng: random.Random, data: bytes) -> bytes:
    """Impossible values for the drone-dji XMP fields, a broken XMP packet, or bytes of the EXIF block."""
    fields = list(re.finditer(rb'drone-dji:(\w+)="([^"]*)"', data))
    op = rng.randrange(4)
    if op == 0 and fields:
        m = rng.choice(fields)
        return data[: m.start(2)] + rng.choice(DJI_FIELD_VALUES).encode() + data[m.end(2) :]
    if op == 1 and fields:
        m = rng.choice(fields)
        return data[: m.start()] + data[m.end() :]
    if op == 2:
        at = data.find(b"<x:xmpmeta")
        if at > 0:
            return data[:at] + _bytes_mutation(rng, data[at : at + 2000]) + data[at + 2000 :]
    exif = data.find(b"Exif\x00\x00")
    if exif > 0 and rng.random() < 0.7:
        end = min(len(data), exif + 600)
        return data[:exif] + _bytes_mutation(rng, data[exif:end]) + data[end:]
    return _bytes_mutation(rng, data)


# ---------------------------------------------------------------------------------------------- seeds
def _citygml_excerpt(path: Path, members: int = 3) -> bytes:
    """The header, the first ``members`` cityObjectMembers and the closing tag of a CityGML file."""
    data = path.read_bytes()
    start = data.find(b"cityObjectMember")
    start = data.rfind(b"<", 0, start)
    end = start
    for _ in range(members):
        nxt = data.find(b"cityObjectMember>", end + 20)
        if nxt < 0:
            break
        end = nxt + len(b"cityObjectMember>")
    close = data.rfind(b"</")
    return data[:end] + b"\n" + data[close:]


def _obj_excerpt(path: Path, vertices: int = 400) -> bytes:
    """The first ``vertices`` vertices of an OBJ and the faces that use only them."""
    out, n = [], 0
    for line in path.read_bytes().split(b"\n"):
        if line.startswith(b"v "):
            n += 1
            if n <= vertices:
                out.append(line)
        elif line.startswith(b"f "):
            idx = [int(t.split(b"/")[0]) for t in line.split()[1:]]
            if all(0 < i <= vertices for i in idx):
                out.append(line)
    return b"\n".join(out) + b"\n"


def real_seeds(target: str) -> list[tuple[str, bytes]]:
    """Excerpts of the real files in ../shared/data for ``target`` (empty when the folder is absent)."""
    d = SHARED_DATA
    if not d.is_dir():
        return []
    uav = d / "real_uav_lodloc"
    stem = "DJI_20230513163714_0033_T"
    if target == "citygml":
        return [
            (p.name, _citygml_excerpt(p))
            for p in (
                d / "berlin_lod2_citygml2/3910_5817.gml",
                d / "fuerth_lod2_citygml1/LOD2_4424_5482_solid.gml",
                d / "lod3_fzk_haus/FZK-Haus-LoD3-KIT-IAI-KHH-B36-V1.gml",
                d / "citygml3/Opera-Lyon_CityGML3.0_LOD2_with_xAL3_FreeText.gml",
                d / "citygml3/53394517_bldg_6697_2_op_CityGML3.gml",
            )
            if p.is_file()
        ]
    if target == "cityjson":
        seeds = [(p.name, p.read_bytes()) for p in (d / "cityjson_nl").glob("*_*.json")]
        delft = d / "cityjson_nl/delft.json"
        if delft.is_file():  # 160 buildings: a few of them, with the whole vertex list
            doc = json.loads(delft.read_bytes())
            keep = [k for k, v in doc["CityObjects"].items() if v.get("type") == "Building"][:5]
            doc["CityObjects"] = {k: doc["CityObjects"][k] for k in keep}
            seeds.append(("delft_5.json", json.dumps(doc).encode()))
        zipped = d / "denhaag_lod2/DenHaag_01.zip"
        if zipped.is_file():  # CityJSON 0.8
            with zipfile.ZipFile(zipped) as z:
                doc = json.loads(z.read("DenHaag/DenHaag_01.json"))
            keep = list(doc["CityObjects"])[:6]
            doc["CityObjects"] = {k: doc["CityObjects"][k] for k in keep}
            seeds.append(("denhaag_6.json", json.dumps(doc).encode()))
        return seeds
    if target == "obj" and (uav / "UAVD4L-LoD1.obj").is_file():
        return [("UAVD4L-LoD1_excerpt.obj", _obj_excerpt(uav / "UAVD4L-LoD1.obj"))]
    if target == "pose":
        return [(p.name, p.read_bytes()) for p in sorted(uav.glob("*_pose/*.txt"))]
    if target == "intrinsics":
        return [(p.name, p.read_bytes()) for p in sorted(uav.glob("intrinsic/*.txt"))]
    if target == "dji":
        return [
            (p.name, p.read_bytes())
            for p in (uav / f"Query_image/{stem}.JPG",)
            if p.is_file() and p.stat().st_size < 2_000_000
        ]
    return []


def synthetic_seeds(target: str, work: Path) -> list[tuple[str, bytes]]:
    """Small valid files made here, so that every target has seeds on any machine."""
    if target in ("citygml", "obj"):
        paths = generate_city(work / "gen", seed=0, blocks=(1, 1))
        if target == "obj":
            obj = export_model(read_citygml(paths[1]), work / "gen.obj")
            return [("generated.obj", obj.read_bytes())]
        return [(p.name, _citygml_excerpt(p, 2)) for p in paths.values()]
    if target == "cityjson":
        doc = box_doc()
        header = {**doc, "CityObjects": {}, "vertices": []}
        feature = {
            "type": "CityJSONFeature",
            "id": "B1",
            "CityObjects": doc["CityObjects"],
            "vertices": doc["vertices"],
        }
        stream = b"\n".join(json.dumps(x).encode() for x in (header, feature, feature))
        return [("box.json", json.dumps(box_doc()).encode()), ("box.city.jsonl", stream)]
    if target == "pose":
        return [
            ("pose.txt", b"1 0 0 10\n0 -1 0 20\n0 0 -1 100\n0 0 0 1\n"),
            ("pose.json", b'{"xyz": [1, 2, 100], "roll": 0, "pitch": 10, "yaw": 30}'),
            ("colmap_line.txt", b"img.jpg 0.7071068 0.7071068 0 0 1 2 3\n"),
            ("inline.txt", b"1,2,100,0,5,30"),
        ]
    if target == "intrinsics":
        return [
            ("k.txt", b"1125 0 320 0\n0 1125 256 0\n0 0 1 0\n"),
            ("cam.txt", b"1 PINHOLE 640 512 1125 1125 320 256\n"),
            ("cam.json", b'{"fx": 1125, "fy": 1125, "cx": 320, "cy": 256, "width": 640, "height": 512}'),
            ("inline.txt", b"1125,1125,320,256,640,512"),
        ]
    if target == "colmap_text":
        return [(name, data) for name, data in COLMAP_TEXT.items()]
    if target == "colmap_binary":
        folder = work / "colmap_txt"
        folder.mkdir(parents=True, exist_ok=True)
        for name, data in COLMAP_TEXT.items():
            (folder / name).write_bytes(data)
        out = write_model(read_model(folder, ".txt"), work / "colmap_bin", ext=".bin")
        return [(p.name, p.read_bytes()) for p in sorted(out.glob("*.bin"))]
    if target == "lodloc_split":
        return [("split.json", b'{"val": {"scene1": ["a.JPG", "Query_image/b.JPG"]}, "train": {"s": []}}')]
    if target == "labels":
        mask = np.zeros((48, 64), np.uint8)
        mask[10:30, 5:40], mask[30:, :] = 1, 3
        mask[0, 0] = 255
        save_labels_png(mask, work / "mask.png")
        buf = io.BytesIO()
        np.save(buf, mask)
        return [("mask.png", (work / "mask.png").read_bytes()), ("mask.npy", buf.getvalue())]
    if target == "depth":
        depth = np.add.outer(np.linspace(50, 90, 48), np.linspace(0, 5, 64)).astype(np.float32)
        png, npy = save_depth(depth, work / "depth.png")
        return [("depth.png", png.read_bytes()), ("depth.npy", npy.read_bytes())]
    if target == "dji":
        dji_jpeg(work / "dji.jpg", xmp=xmp_packet(**RTK_FIELDS), gps=(48.1, 11.5, 612.5), focal_35mm=24)
        return [("dji.jpg", (work / "dji.jpg").read_bytes())]
    if target == "geotags":
        return [
            (
                "geotags.csv",
                b"image,latitude,longitude,height_m,yaw_deg,pitch_deg,roll_deg,accuracy_xy_m,accuracy_z_m,source\n"
                b"DJI_0001.JPG,52.5163,13.3777,112.4,-31.5,-90.0,0.0,0.02,0.03,rtk\n"
                b"DJI_0002.JPG,52.5165,13.3779,112.9,148.2,-45.1,0.1,,,gnss\n",
            ),
            ("odm_like.txt", b"name;lat;lon;alt;yaw;pitch\nIMG_1.jpg;48.1;11.5;612.5;10;-60\n"),
        ]
    raise KeyError(target)


COLMAP_TEXT = {
    "cameras.txt": b"# Camera list\n1 PINHOLE 640 512 1125 1125 320 256\n"
    b"2 SIMPLE_RADIAL 800 600 700 400 300 0.01\n",
    "images.txt": b"# Image list\n1 0.7071068 0 0.7071068 0 1 2 3 1 a.jpg\n100 200 1\n"
    b"2 1 0 0 0 4 5 6 2 b.jpg\n\n",
    "points3D.txt": b"1 1.0 2.0 3.0 255 0 0 0.5 1 0\n",
}


# --------------------------------------------------------------------------------------------- targets
def _read_colmap(folder: Path, name: str, data: bytes, ext: str, seeds: dict[str, bytes]) -> object:
    for other, content in seeds.items():
        (folder / other).write_bytes(content)
    (folder / name).write_bytes(data)
    return read_model(folder, ext)


@dataclass
class Target:
    """A reader under fuzz: ``read(path)`` of one file named like its seed (suffix kept)."""

    name: str
    mutate: Callable[[random.Random, bytes], bytes]
    read: Callable[[Path], object]


TARGETS: dict[str, Target] = {
    "citygml": Target("citygml", xml_mutation, lambda p: read_citygml(p)),
    "cityjson": Target("cityjson", json_mutation, lambda p: read_cityjson(p)),
    "obj": Target("obj", obj_mutation, lambda p: read_obj(p)),
    "pose": Target("pose", text_mutation, lambda p: read_pose(p)),
    "intrinsics": Target("intrinsics", text_mutation, lambda p: read_intrinsics(p)),
    "colmap_text": Target("colmap_text", text_mutation, None),
    "colmap_binary": Target("colmap_binary", _bytes_mutation, None),
    "lodloc_split": Target("lodloc_split", json_mutation, lambda p: read_split(p)),
    "labels": Target("labels", image_mutation, lambda p: read_mask_file(p)),
    "depth": Target("depth", image_mutation, lambda p: read_depth_file(p)),
    "dji": Target("dji", dji_mutation, lambda p: read_dji_metadata(p)),
    "geotags": Target("geotags", text_mutation, lambda p: read_geotags_csv(p)),
}


class Fuzzer:
    """Seeds and one-input runs of a target, in a scratch folder ``work``."""

    def __init__(self, target: str, work: Path, real: bool = True):
        self.target = TARGETS[target]
        self.work = work
        (work / "seeds").mkdir(parents=True, exist_ok=True)
        self.seeds = synthetic_seeds(target, work / "seeds") + (real_seeds(target) if real else [])
        self._colmap = dict(self.seeds) if target.startswith("colmap") else {}

    def input(self, rng: random.Random) -> tuple[str, bytes]:
        """A seed with 1-4 mutations."""
        name, data = rng.choice(self.seeds)
        for _ in range(rng.choice([1, 1, 1, 2, 3, 4])):
            data = self.target.mutate(rng, data)
        return name, data

    def run(self, name: str, data: bytes) -> tuple[str, BaseException | None]:
        """(outcome, the exception) of reading ``data`` as a file called ``name``."""
        folder = self.work / "input"
        folder.mkdir(exist_ok=True)
        try:
            if self._colmap:
                ext = Path(name).suffix
                seeds = {k: v for k, v in self._colmap.items() if k.endswith(ext)}
                _read_colmap(folder, name, data, ext, seeds)
            else:
                path = folder / name
                path.write_bytes(data)
                self.target.read(path)
        except SemCityLocError as exc:
            return TYPED, exc
        except Exception as exc:  # noqa: BLE001 (anything else is what fuzzing looks for)
            return CRASH, exc
        return VALID, None
