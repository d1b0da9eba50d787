"""A CityGML file opened and parsed safely: the parser settings, gzip, entity refusal and read errors.

Why a module of its own: a city model file comes from anywhere, and XML carries known attacks (entity
expansion, a "billion laughs"; external entities that read local files or the network, XXE). Every parse of
a CityGML file goes through this module, so one place decides what the parser may do:

- ``PARSER_OPTIONS``: never resolve entities, never load a DTD, never touch the network, libxml2's default
  size limits; no id hash table (the reader indexes gml:ids itself, bounded).
- ``root_element``: the root tag, read before streaming; a DOCTYPE that declares entities is refused
  (``MalformedXMLError``): CityGML never uses them, and leaving them unexpanded would silently drop text.
  An external DTD is never loaded, only named (``external_entity_error`` when nothing could be read and the
  document uses one of its entities).
- ``reading``: the file as a binary stream (gzip by its magic bytes, decompressed on the fly, under
  ``limits``' size limit), with every parser, gzip and read failure turned into a typed error naming the
  file.
"""

from __future__ import annotations

import gzip
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO

from lxml import etree

from semcityloc.citymodel.limits import check_file_size
from semcityloc.errors import InputFileError, MalformedXMLError

# The safe parser settings (also used for the root sniff): no entity expansion, no DTD, no network, libxml2's
# default size limits (huge_tree=False), and no id hash table (we index gml:ids ourselves, bounded).
PARSER_OPTIONS = dict(
    resolve_entities=False,
    no_network=True,
    load_dtd=False,
    dtd_validation=False,
    huge_tree=False,
    remove_comments=True,
    remove_pis=True,
    collect_ids=False,
    recover=False,
)


def _xml_error(path: Path, exc: etree.XMLSyntaxError) -> MalformedXMLError:
    if "amplification" in str(exc.msg):  # libxml2 stopped an entity expansion: a hostile file, not a typo
        return MalformedXMLError(
            f"{path}: refused: its DTD declares entities that expand without bound (a 'billion laughs' or "
            f"quadratic-blowup document, line {exc.lineno}); city models need no entities"
        )
    return MalformedXMLError(f"{path}: not well-formed XML, line {exc.lineno}: {exc.msg}")


def open_citygml(path: Path) -> IO[bytes]:
    """The file as a binary stream; gzip (by its magic bytes) is decompressed on the fly."""
    try:
        fh = open(path, "rb")  # noqa: SIM115 - returned to the caller, who closes it
    except FileNotFoundError as exc:
        raise InputFileError(f"{path}: no such file") from exc
    except IsADirectoryError as exc:
        raise InputFileError(f"{path}: is a directory, not a CityGML file") from exc
    except OSError as exc:
        raise InputFileError(f"{path}: cannot open ({exc.strerror or exc})") from exc
    check_file_size(path, "CityGML")
    if fh.read(2) == b"\x1f\x8b":
        fh.seek(0)
        return gzip.GzipFile(fileobj=fh, mode="rb")
    fh.seek(0)
    return fh


@contextmanager
def reading(path: Path) -> Iterator[IO[bytes]]:
    """The open file (``open_citygml``) for one parse, closed after it; a parse error is a
    ``MalformedXMLError`` (a broken gzip stream too), a read error an ``InputFileError``, naming the file."""
    fh = open_citygml(path)
    try:
        yield fh
    except etree.XMLSyntaxError as exc:
        raise _xml_error(path, exc) from exc
    except (EOFError, zlib.error, gzip.BadGzipFile) as exc:
        raise MalformedXMLError(f"{path}: truncated or corrupt gzip stream ({exc})") from exc
    except OSError as exc:
        raise InputFileError(f"{path}: read error ({exc})") from exc
    finally:
        fh.close()


def root_element(path: Path) -> tuple[str, str | None]:
    """The root element's tag (empty if it has none) and the DOCTYPE's external DTD (None without one), from
    the first element only; a DOCTYPE that declares entities is refused before the whole file is streamed."""
    with reading(path) as fh:
        _, root = next(iter(etree.iterparse(fh, events=("start",), **PARSER_OPTIONS)))
        docinfo = root.getroottree().docinfo
    dtd = docinfo.internalDTD
    if dtd is not None and any(True for _ in dtd.iterentities()):
        raise MalformedXMLError(
            f"{path}: the DOCTYPE declares XML entities; CityGML does not use them and they are "
            "refused (entity expansion is a known attack)"
        )
    external_dtd = docinfo.system_url or docinfo.public_id or None
    return (root.tag if isinstance(root.tag, str) else ""), external_dtd


def first_entity_reference(path: Path) -> str | None:
    """The name of the first (unexpanded) entity reference in the document, or None."""
    fh = open_citygml(path)
    try:
        for _, el in etree.iterparse(fh, events=("end",), **PARSER_OPTIONS):
            for child in el:
                if isinstance(child, etree._Entity):
                    return child.name
            el.clear()
    except (etree.XMLSyntaxError, EOFError, zlib.error, gzip.BadGzipFile, OSError):
        return None
    finally:
        fh.close()
    return None


def external_entity_error(path: Path, external_dtd: str | None) -> MalformedXMLError | None:
    """For a document from which nothing could be read: the error naming the external DTD and the entity of
    it the document uses (never loaded: that is how XXE attacks read files and the network), or None when it
    has no external DTD or uses none of its entities."""
    if external_dtd is None:
        return None
    entity = first_entity_reference(path)
    if entity is None:
        return None
    return MalformedXMLError(
        f"{path}: no building surfaces could be read: the document uses the entity "
        f"&{entity}; declared in the external DTD {external_dtd!r}, which is never loaded "
        "(external DTDs and entities are refused: they are how XXE attacks read files and the "
        "network)"
    )
