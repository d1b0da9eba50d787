"""Test helper: JPEGs with DJI-style metadata (an XMP packet of ``drone-dji:`` fields, EXIF GPS and focal
length), as DJI aircraft write them. Imported by the tests (``tests/`` is on ``sys.path``)."""

from __future__ import annotations

import io
import struct

import numpy as np
from PIL import Image

# An RTK-fixed DJI photo over Munich looking at the horizon due north (the XMP fields DJI writes).
RTK_FIELDS = dict(
    GpsLatitude="+48.1000000",
    GpsLongitude="+11.5000000",
    AbsoluteAltitude="+612.500",
    RelativeAltitude="+80.0",
    GimbalYawDegree="+0.00",
    GimbalPitchDegree="+0.00",
    GimbalRollDegree="+0.00",
    AltitudeType="RtkAlt",
    RtkFlag="50",
    RtkStdHgt="0.021",
)


def xmp_packet(**fields) -> bytes:
    attrs = "\n".join(f'   drone-dji:{k}="{v}"' for k, v in fields.items())
    return (
        '<?xpacket begin="\ufeff" id="W5M0MpCehiHzreSzNTczkc9d"?>\n<x:xmpmeta xmlns:x="adobe:ns:meta/">\n'
        ' <rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">\n'
        '  <rdf:Description rdf:about="DJI Meta Data" xmlns:drone-dji="http://www.dji.com/drone-dji/1.0/"\n'
        f'{attrs}>\n  </rdf:Description>\n </rdf:RDF>\n</x:xmpmeta>\n<?xpacket end="w"?>'
    ).encode()


def dji_jpeg(
    path, xmp: bytes | None = None, gps: tuple | None = None, size=(64, 48), focal_35mm=None, pixels=None
):
    """A JPEG with an EXIF GPS block (lat, lon, alt), EXIF FocalLengthIn35mmFilm and an XMP APP1 segment,
    as DJI writes them; ``pixels``: (H, W, 3) uint8 content (default flat grey of ``size``)."""
    exif = Image.Exif()
    exif[271], exif[272] = "DJI", "M3E"
    if gps is not None:
        lat, lon, alt = gps
        g = exif.get_ifd(0x8825)

        def dms(v):
            d = int(abs(v))
            m = int((abs(v) - d) * 60)
            return (float(d), float(m), (abs(v) - d - m / 60) * 3600)

        g[1], g[2], g[3], g[4] = ("N" if lat >= 0 else "S"), dms(lat), ("E" if lon >= 0 else "W"), dms(lon)
        g[5], g[6] = b"\x00", float(alt)
    if focal_35mm is not None:
        exif.get_ifd(0x8769)[41989] = int(focal_35mm)
    image = Image.fromarray(np.asarray(pixels, dtype=np.uint8)) if pixels is not None else None
    image = image or Image.new("RGB", size, (90, 90, 90))
    buf = io.BytesIO()
    image.save(buf, "JPEG", exif=exif)
    data = buf.getvalue()
    if xmp is not None:
        payload = b"http://ns.adobe.com/xap/1.0/\x00" + xmp
        data = data[:2] + b"\xff\xe1" + struct.pack(">H", len(payload) + 2) + payload + data[2:]
    path.write_bytes(data)
    return path
