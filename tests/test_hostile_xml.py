"""Hostile CityGML: XXE, entity bombs, external DTDs, XInclude, absurd nesting.

The reader must never read a local file or touch the network because a document asked it to, must refuse
entity bombs (``MalformedXMLError``) without expanding them, and must never raise anything but the
library's typed errors. How fast a bomb is refused is a speed goal, measured by
``benchmarks/hostile_scale.py --bombs`` (house rule: speed goals live in benchmarks/, not in timed unit
tests); here an expansion shows as the test process's peak memory growing.
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from lxml import etree

from semcityloc.citymodel.citygml import read_citygml
from semcityloc.citymodel.citygml_xml import PARSER_OPTIONS
from semcityloc.errors import MalformedXMLError

SECRET = "TOP-SECRET-7f3a9c-DO-NOT-LEAK"

HEAD = (
    '<CityModel xmlns="http://www.opengis.net/citygml/2.0" xmlns:bldg="http://www.opengis.net/citygml/building/2.0"'
    ' xmlns:gml="http://www.opengis.net/gml" xmlns:xlink="http://www.w3.org/1999/xlink"'
    ' xmlns:xi="http://www.w3.org/2001/XInclude">'
)
ROOF = (
    "<bldg:boundedBy><bldg:RoofSurface><bldg:lod2MultiSurface><gml:MultiSurface><gml:surfaceMember><gml:Polygon>"
    "<gml:exterior><gml:LinearRing><gml:posList>391000 5817000 10 391010 5817000 10 391010 5817010 10 "
    "391000 5817010 10 391000 5817000 10</gml:posList></gml:LinearRing></gml:exterior></gml:Polygon>"
    "</gml:surfaceMember></gml:MultiSurface></bldg:lod2MultiSurface></bldg:RoofSurface></bldg:boundedBy>"
)


def _doc(doctype: str, name_text: str = "house") -> str:
    return (
        f'<?xml version="1.0" encoding="UTF-8"?>\n{doctype}\n{HEAD}<cityObjectMember>'
        f'<bldg:Building gml:id="B1"><gml:name>{name_text}</gml:name>{ROOF}</bldg:Building>'
        "</cityObjectMember></CityModel>\n"
    )


@pytest.fixture
def secret(tmp_path) -> Path:
    path = tmp_path / "secret.txt"
    path.write_text(SECRET)
    return path


def _everything_said(model) -> str:
    """Every string the model carries (ids, warnings, source) plus its summary."""
    return json.dumps(model.summary()) + " ".join(model.building_ids) + " ".join(model.stats.warnings)


def _assert_not_leaked(path: Path) -> None:
    """The safe parser settings alone (without the DOCTYPE refusal) leave the entity unexpanded."""
    parsed = b""
    for _, el in etree.iterparse(str(path), events=("end",), **PARSER_OPTIONS):
        parsed += etree.tostring(el)
    assert parsed and SECRET.encode() not in parsed


def test_xxe_external_entity_is_refused_and_never_read(tmp_path, secret):
    path = tmp_path / "xxe.gml"
    path.write_text(_doc(f'<!DOCTYPE CityModel [<!ENTITY x SYSTEM "file://{secret}">]>', "&x;"))
    with pytest.raises(MalformedXMLError, match="entit") as info:
        read_citygml(path)
    assert SECRET not in str(info.value)
    _assert_not_leaked(path)


def test_xxe_parameter_entity_is_refused(tmp_path, secret):
    dtd = tmp_path / "evil.dtd"
    dtd.write_text(f'<!ENTITY x SYSTEM "file://{secret}">')
    path = tmp_path / "pxxe.gml"
    path.write_text(_doc(f'<!DOCTYPE CityModel [<!ENTITY % p SYSTEM "file://{dtd}"> %p;]>', "&x;"))
    with pytest.raises(MalformedXMLError) as info:
        read_citygml(path)
    assert SECRET not in str(info.value)


def test_external_file_dtd_is_not_loaded(tmp_path, secret):
    # The external DTD would declare &x; as the secret file; it is never loaded, so &x; stays a reference.
    dtd = tmp_path / "evil.dtd"
    dtd.write_text(f'<!ENTITY x SYSTEM "file://{secret}">')
    path = tmp_path / "extdtd.gml"
    path.write_text(_doc(f'<!DOCTYPE CityModel SYSTEM "file://{dtd}">', "&x;"))
    try:
        model = read_citygml(path)
    except MalformedXMLError as exc:  # refusing is acceptable too, leaking is not
        assert SECRET not in str(exc)
    else:
        assert SECRET not in _everything_said(model)
        assert model.class_areas()["roof"] == pytest.approx(100.0)
        assert any("DTD" in w for w in model.stats.warnings)
    _assert_not_leaked(path)


def test_xinclude_is_not_processed(tmp_path, secret):
    path = tmp_path / "xi.gml"
    path.write_text(_doc("", f'<xi:include href="file://{secret}" parse="text"/>'))
    model = read_citygml(path)
    assert SECRET not in _everything_said(model)
    _assert_not_leaked(path)


def _lol_doctype(levels: int = 10) -> str:
    lines = ['<!ENTITY lol0 "lol">']
    for i in range(1, levels):
        lines.append(f'<!ENTITY lol{i} "{f"&lol{i - 1};" * 10}">')
    return "<!DOCTYPE CityModel [\n" + "\n".join(lines) + "\n]>"


def _peak_growth(fn) -> tuple[float, BaseException | None]:
    """(MB the test process's peak RSS grew by while running ``fn``, the exception it raised or None)."""
    peak0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    err = None
    try:
        fn()
    except BaseException as exc:  # noqa: BLE001 - returned to the test, which checks its type
        err = exc
    grown_mb = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - peak0) / 1024.0
    return grown_mb, err


def test_billion_laughs_fails_fast(tmp_path):
    path = tmp_path / "lol.gml"
    path.write_text(_doc(_lol_doctype(10), "&lol9;"))
    grown_mb, err = _peak_growth(lambda: read_citygml(path))
    assert isinstance(err, MalformedXMLError), err
    assert "entities that expand without bound (a 'billion laughs'" in str(err)  # not "not well-formed"
    assert grown_mb < 50  # the peak RSS of the test process did not grow: nothing was expanded


def test_quadratic_blowup_fails_fast(tmp_path):
    path = tmp_path / "quad.gml"
    doctype = f'<!DOCTYPE CityModel [<!ENTITY a "{"x" * 100_000}">]>'
    path.write_text(_doc(doctype, "&a;" * 20_000))  # 2 GB if expanded
    grown_mb, err = _peak_growth(lambda: read_citygml(path))
    assert isinstance(err, MalformedXMLError), err
    assert "entities that expand without bound" in str(err)
    assert grown_mb < 50


def test_billion_laughs_with_the_parser_settings_alone(tmp_path):
    # Defence in depth: even without the DOCTYPE refusal, the parser does not expand the bomb.
    path = tmp_path / "lol.gml"
    path.write_text(_doc(_lol_doctype(10), "&lol9;"))

    def parse():
        for _ in etree.iterparse(str(path), events=("end",), **PARSER_OPTIONS):
            pass

    grown_mb, _ = _peak_growth(parse)
    assert grown_mb < 50


def test_external_http_dtd_is_never_fetched(tmp_path):
    # 10.255.255.1 is unroutable: a fetch would hang until the TCP connect timeout (over a minute). The read
    # runs in a child process whose timeout is the hang guard, not a speed goal: the child takes about 3 s
    # here (its imports), so only a fetch reaches 60 s, and a regression fails instead of hanging the suite.
    path = tmp_path / "http_dtd.gml"
    path.write_text(
        _doc(
            '<!DOCTYPE CityModel PUBLIC "-//EVIL//DTD CityGML//EN" "http://10.255.255.1/citygml.dtd">',
            "house",
        )
    )
    code = textwrap.dedent(
        f"""
        import json
        from semcityloc.citymodel.citygml import read_citygml
        try:
            m = read_citygml({str(path)!r})
            out = {{"ok": True, "roof": m.class_areas()["roof"], "warnings": m.stats.warnings}}
        except Exception as exc:
            out = {{"ok": False, "error": type(exc).__name__, "msg": str(exc)}}
        print(json.dumps(out))
        """
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    if out["ok"]:
        assert out["roof"] == pytest.approx(100.0)
        assert any("not loaded" in w for w in out["warnings"])
    else:
        assert out["error"] == "MalformedXMLError"


def test_absurd_nesting_is_refused(tmp_path):
    # libxml2's default depth limit (no huge_tree) keeps the recursive geometry walk far from Python's limit.
    depth = 5000
    path = tmp_path / "deep.gml"
    inner = "<gml:MultiSurface>" * depth + "</gml:MultiSurface>" * depth
    path.write_text(
        _doc("", "house").replace(ROOF, f"<bldg:lod2MultiSurface>{inner}</bldg:lod2MultiSurface>")
    )
    with pytest.raises(MalformedXMLError, match="line"):
        read_citygml(path)
