"""A message of the library names what to pass as a Python caller passes it; the command line, its flag.

Before stop 52 the lower layers worded their errors, warnings and notes with the command line's flags
(``run again with --prior-sigma z=8``, ``(--crs: 'EPSG:4326')``, ``save masks as PNG (--allow-lossy-mask
of semcityloc localize ...)``), which a caller of ``Localizer.localize`` or ``load_city_model`` never
passed. Each now names the parameter through ``errors.parameter`` (one table, ``errors.PARAMETERS``), and
what the command prints and a run folder keeps turns it into the flag (``errors.as_flags``).
"""

from __future__ import annotations

import argparse
import ast
import json
import re
import zipfile
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import semcityloc
from dji_photo import RTK_FIELDS, dji_jpeg, xmp_packet
from semcityloc.benchmark.runfiles import RUN_FILE, prepare_output
from semcityloc.citymodel.io import load_city_model
from semcityloc.citymodel.tiles import TILES_DIR, TileStore, build_store
from semcityloc.cli.main import build_parser, main
from semcityloc.datasets.dji import dji_prior, read_dji_metadata
from semcityloc.datasets.photos import EXIF, PriorFiles
from semcityloc.errors import PARAMETERS, ResumeMismatchError, SemCityLocError, as_flags, parameter
from semcityloc.geometry.uncertainty import PriorUncertainty
from semcityloc.io.images import load_labels_png
from semcityloc.localization.cascade import search_volume
from semcityloc.localization.config import CascadeConfig
from semcityloc.localization.focal_check import FocalCheck, corrected_warning, focal_warning
from semcityloc.localization.search_reach import edge_warning

FLAG = re.compile(r"(?<![\w-])--[a-z]")  # a command-line flag
# A command of the command line named in a message: ``semcityloc tiles build``, ``'semcityloc warmup'``.
COMMANDS = "tiles|warmup|run|localize|label|train-segmenter|benchmark|render|city|dataset|report|sweep|demo"
COMMAND = re.compile(rf"\bsemcityloc (?:{COMMANDS})(?![\w-])")
X0, Y0 = 391000.0, 5819000.0  # metres of EPSG:25833 (Berlin)


def _citygml(path, srs: str = "EPSG:25833"):
    """One building of one wall in metres of ``srs``, as a CityGML 2.0 file."""
    ring = [(X0, Y0, 30), (X0 + 9, Y0, 30), (X0 + 9, Y0, 40), (X0, Y0, 40), (X0, Y0, 30)]
    pos = " ".join(f"{x} {y} {z}" for x, y, z in ring)
    path.write_text(
        '<?xml version="1.0" encoding="UTF-8"?>\n'
        '<core:CityModel xmlns:core="http://www.opengis.net/citygml/2.0" '
        'xmlns:bldg="http://www.opengis.net/citygml/building/2.0" xmlns:gml="http://www.opengis.net/gml">'
        '<core:cityObjectMember><bldg:Building gml:id="B"><bldg:lod2MultiSurface>'
        f'<gml:MultiSurface srsName="{srs}"><gml:surfaceMember><gml:Polygon><gml:exterior><gml:LinearRing>'
        f"<gml:posList>{pos}</gml:posList></gml:LinearRing></gml:exterior></gml:Polygon></gml:surfaceMember>"
        "</gml:MultiSurface></bldg:lod2MultiSurface></bldg:Building></core:cityObjectMember></core:CityModel>",
        encoding="utf-8",
    )
    return path


def _said(call) -> str:
    with pytest.raises(SemCityLocError) as info:
        call()
    return str(info.value)


def test_library_messages_name_the_python_parameter_and_no_flag(tmp_path):
    """Refusals, warnings and notes of the lower layers met from Python: each names the keyword the caller
    has, never a flag; the same text through ``as_flags`` names the flag."""
    gml = _citygml(tmp_path / "city.gml")
    jpeg_mask = tmp_path / "mask.png"
    Image.fromarray(np.zeros((6, 8), np.uint8), mode="L").save(jpeg_mask, format="JPEG")
    (tmp_path / "store" / TILES_DIR).mkdir(parents=True)  # a store whose build stopped before its index
    meta = read_dji_metadata(dji_jpeg(tmp_path / "a.jpg", xmp_packet(**RTK_FIELDS)))
    cascade = CascadeConfig()
    volume = search_volume(np.zeros(6), PriorUncertainty(), cascade)

    said = {
        "crs='EPSG:4326'": _said(lambda: load_city_model(gml, crs="EPSG:4326", cache=False)),
        "crs='EPSG:25832' overrides": " ".join(
            load_city_model(gml, crs="EPSG:25832", cache=False).stats.warnings
        ),
        "priors='GPS_pose/'": _said(lambda: PriorFiles(EXIF, None)),
        "prior_uncertainty=PriorUncertainty.parse('z=": edge_warning(["z-"], volume, cascade),
        "build_store(TILES, STORE, overwrite=True)": _said(lambda: TileStore.open(tmp_path / "store")),
        "allow_lossy=True": _said(lambda: load_labels_png(jpeg_mask)),
        "target_height='ellipsoidal'": " ".join(
            dji_prior(meta, "EPSG:25832", target_height="ellipsoidal", geoid_separation_m=47.0).notes
        ),
        "target_crs='EPSG:<code>'": _said(lambda: dji_prior(meta, "EPSG:4326")),
    }
    for python, text in said.items():
        assert python in text and not FLAG.search(text), text
        assert FLAG.search(as_flags(text)) and python not in as_flags(text)
    assert "geoid_separation_m=..." in said["target_height='ellipsoidal'"]
    # The uncertainty a refusal asks for is one a Python caller can pass as it is written.
    asked = re.search(
        r"PriorUncertainty\.parse\('([^']*)'\)", said["prior_uncertainty=PriorUncertainty.parse('z="]
    )
    assert PriorUncertainty.parse(asked.group(1)).z_m > PriorUncertainty().z_m
    assert as_flags(said["prior_uncertainty=PriorUncertainty.parse('z="]).endswith(
        f"with --prior-sigma {asked.group(1)} or correct the prior"
    )


def test_the_focal_length_warning_names_what_a_localize_caller_sets():
    """Stop 55 audit: the focal-length warnings told a Python caller to pass ``intrinsics='FILE'``, a
    parameter ``Localizer.localize`` does not have (it takes a ``camera``). They now name the camera's
    calibrated ``fx`` / ``fy`` (and a photo run's ``PhotoSpec(intrinsics='FILE')``); the command line
    still prints ``--intrinsics FILE``."""
    check = FocalCheck(1.02, (-0.02, -0.002), 0.03, 80.0)
    for text in (focal_warning(check, 0.01), corrected_warning(check, 1.03)):
        said = text.split("calibrated intrinsics (")[1]
        assert said.startswith("camera=Camera(fx=..., fy=...") and "PhotoSpec(intrinsics='FILE')" in said
        assert not FLAG.search(text) and "(--intrinsics FILE, docs/your-data.md" in as_flags(text)
        assert "Camera(" not in as_flags(text) and "--preset focal-correct" in as_flags(
            focal_warning(check, 0.01)
        )


def test_each_parameter_is_one_flag_and_other_text_is_left_alone():
    """Every spelling of ``PARAMETERS`` turns into its flag, inside a sentence, with a value or without,
    once (text turned already stays as it is); words that only look alike are no parameter."""
    for name, entry in PARAMETERS.items():
        valued = as_flags(f"do this ({parameter(name, 'X1')}).")
        assert valued == f"do this ({entry.flag.replace('{}', 'X1')}).", name
        bare = as_flags(f"do this ({parameter(name)}).")
        assert parameter(name) not in bare and (FLAG.search(bare) or COMMAND.search(bare)), (name, bare)
        assert as_flags(valued) == valued and as_flags(bare) == bare
    for text in (
        "target_crs given but the file names no CRS",
        "the store was built with crs=ETRS89 / UTM zone 32N",
        "lod=2, head=DIR, offset=3",
        "pip install --no-deps x",
    ):
        assert as_flags(text) == text
    assert as_flags({"a crs='EPSG:1'": ["offset=..."], "n": 3}) == {"a --crs EPSG:1": ["--offset"], "n": 3}


def test_the_command_line_prints_the_flags(tmp_path, capsys):
    """The same refusals and notes, met through the command: each names the flag the user types, in what
    it prints and in the pose JSON it writes."""
    gml = _citygml(tmp_path / "city.gml")
    assert main(["city", "info", str(gml), "--crs", "EPSG:4326", "--no-cache"]) == 2
    err = capsys.readouterr().err
    assert "pass that one with --crs EPSG:<code> (given as --crs EPSG:4326)" in err and "crs='" not in err

    image = dji_jpeg(tmp_path / "a.jpg", xmp_packet(**RTK_FIELDS))
    out = tmp_path / "prior.json"
    argv = ["dataset", "dji-prior", str(image), "--crs", "EPSG:25832", "--geoid-separation", "47"]
    argv += ["--target-height", "ellipsoidal"]
    assert main([*argv, "--out", str(out)]) == 0
    notes = " ".join(json.loads(out.read_text())["extra"]["notes"])
    assert "the geoid separation given (--geoid-separation) was not used" in notes
    assert (
        "(--target-height ellipsoidal with ellipsoidal photo heights" in notes
        and "target_height=" not in notes
    )


def test_a_resume_is_not_refused_for_a_skipped_photos_reworded_reason(tmp_path):
    """``run.json`` keeps why each photo was skipped, and a resume compared those words: a version that
    words a reason otherwise (a parameter named otherwise) refused every run it had not started. The same
    photos skipped resume, the reasons kept in this version's words; other photos skipped are refused."""
    old = {"mode": "photos", "queries": 2, "query_names": ["a.jpg", "b.jpg"]}
    (tmp_path / RUN_FILE).write_text(
        json.dumps({**old, "skipped_photos": {"c.jpg": "no mask; pass --allow-lossy-mask"}}), encoding="utf-8"
    )
    new = {**old, "skipped_photos": {"c.jpg": "no mask; save it as PNG, or --allow-lossy-mask uses it"}}
    assert prepare_output(tmp_path, new) is not None  # resumed
    assert json.loads((tmp_path / RUN_FILE).read_text())["skipped_photos"] == new["skipped_photos"]
    with pytest.raises(ResumeMismatchError, match="the photos to run differ"):
        prepare_output(tmp_path, {**old, "skipped_photos": {"d.jpg": "no mask"}})


SRC = Path(semcityloc.__file__).resolve().parent  # the package imported, wherever it is


def _message_texts(path: Path) -> list[tuple[int, str]]:
    """The string constants of a module, f-strings' pieces among them, but not its docstrings."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    docs = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                docs.add(id(body[0].value))
    return [
        (node.lineno, node.value)
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docs
    ]


def test_library_messages_name_a_command_only_through_parameters():
    """Stop 52's note: messages of the library named command-line commands (``semcityloc tiles build``,
    ``'semcityloc warmup'``, ``'semcityloc run' / 'semcityloc localize'``, ``semcityloc localize takes one
    image``, ``'semcityloc label'``), which a Python caller does not run. Each now goes through
    ``errors.PARAMETERS`` (the Python function, or the command where the command line prints it): no
    string of the library outside ``cli/`` and that table names a command."""
    found = []
    for path in sorted(SRC.rglob("*.py")):
        if "cli" in path.relative_to(SRC).parts or path.name == "errors.py":
            continue
        found += [f"{path.relative_to(SRC)}:{line}: {text}" for line, text in _message_texts(path)
                  if COMMAND.search(text)]  # fmt: skip
    assert not found, "\n".join(found)


def _command_line_flags(parser: argparse.ArgumentParser) -> set[str]:
    """Every ``--flag`` of ``parser`` and of its subcommands'."""
    found = set()
    for action in parser._actions:
        found |= {o for o in action.option_strings if o.startswith("--")}
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                found |= _command_line_flags(sub)
    return found


def test_library_messages_name_a_flag_only_through_parameters():
    """Stop 54: ``PhotoSpec`` refused ``geoid_separation_m`` with ``target_height='ellipsoidal'`` naming
    ``--geoid-separation`` and ``--target-height``, which a Python caller never passed, and the scan of the
    library's strings looked for commands only; nine benchmark modules named flags too (``--prior-sigma
    z=12`` in a run's notes, ``pass --overwrite or choose another --out``, ``--perception masks needs
    --masks DIR``, ...). No string of the library outside ``cli/`` and ``errors.PARAMETERS`` names a flag of
    the command line now (other programs' flags, ``ray start --head``, are no concern)."""
    flags = _command_line_flags(build_parser()) - {"--help", "--version"}
    found = []
    for path in sorted(SRC.rglob("*.py")):
        if "cli" in path.relative_to(SRC).parts or path.name == "errors.py":
            continue
        for line, text in _message_texts(path):
            said = set(re.findall(r"(?<![\w-])--[a-z][a-z0-9-]*", text)) & flags
            if said:
                found.append(f"{path.relative_to(SRC)}:{line}: {sorted(said)} {text!r}")
    assert "--geoid-separation" in flags and "--target-height" in flags and "--set" in flags
    assert not found, "\n".join(found)


def test_a_folder_of_tiles_or_a_zipped_tile_names_build_store_or_tiles_build(tmp_path, capsys):
    """The refusal of a folder of tiles given as a city model names ``build_store(TILES, STORE)`` to a Python
    caller and ``semcityloc tiles build TILES --out STORE`` on the command line; ``store.json`` speaks the
    command line's words (``skipped_tiles``: a zipped tile left out), as a run folder does, while the build's
    report keeps the Python ones."""
    tiles = tmp_path / "tiles"
    tiles.mkdir()
    _citygml(tiles / "a.gml")
    said = _said(lambda: load_city_model(tiles, cache=False))
    assert "build_store(TILES, STORE) makes a store of them" in said and not COMMAND.search(said)
    assert main(["city", "info", str(tiles), "--no-cache"]) == 2
    err = capsys.readouterr().err
    assert (
        "'semcityloc tiles build TILES --out STORE' makes a store of them" in err and "build_store" not in err
    )
    with zipfile.ZipFile(tiles / "b.gml", "w") as z:
        z.write(_citygml(tmp_path / "x.gml"), "x.gml")
    report = build_store(tiles, tmp_path / "store")
    assert "their folder to build_store(TILES, STORE)" in report.skipped["b.gml"]
    kept = json.loads((tmp_path / "store" / "store.json").read_text())["skipped_tiles"]["b.gml"]
    assert "their folder to 'semcityloc tiles build TILES --out STORE'" in kept and "build_store" not in kept
    assert main(["tiles", "build", str(tiles), "--out", str(tmp_path / "store2")]) == 0
    kept = json.loads((tmp_path / "store2" / "store.json").read_text())["skipped_tiles"]["b.gml"]
    assert "'semcityloc tiles build TILES --out STORE'" in kept
