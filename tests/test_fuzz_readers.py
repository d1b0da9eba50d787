"""Fuzzing slice: every reader answers mutated files with a result or a typed error, never a crash.

A short, seeded, deterministic run of the targets in ``fuzzing.py`` (``make fuzz`` runs >= 10,000 inputs
per target: ``tests/fuzz_run.py``, table in docs/reliability.md), driven by hypothesis; then one regression
test per crash fuzzing found (each was a traceback from numpy, Pillow or the struct module before).
"""

from __future__ import annotations

import io
import json
import random
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from PIL import Image

from fuzzing import CRASH, SHARED_DATA, TARGETS, Fuzzer, real_seeds
from semcityloc.citymodel.cityjson import read_cityjson
from semcityloc.citymodel.obj import read_obj
from semcityloc.datasets.colmap import read_images_text, read_points3D_text
from semcityloc.datasets.dji_metadata import read_dji_metadata
from semcityloc.errors import CameraError, EmptyModelError, InputFileError, MalformedCityJSONError, PoseError
from semcityloc.geometry.io import read_intrinsics, read_pose
from semcityloc.io.images import load_image, read_depth_file, read_mask_file
from test_cityjson import box_doc, write

SLICE = settings(
    max_examples=25,
    derandomize=True,
    database=None,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
# A hang guard, not a speed goal: the slowest mutated input takes about 0.35 s (a CityGML, on the shared
# 2-core machine), so only a hang or an exponential blow-up reaches 10 s (30x that). The readers' speed on
# fuzzed input is measured by ``make fuzz`` (``tests/fuzz_run.py``), not here.
HANG_GUARD_S = 10.0
# Corrupt inputs make Pillow warn (broken EXIF): a warning is an answer too. A numpy RuntimeWarning is not:
# it means a corrupt value reached arithmetic (NaN coordinates, a signalling NaN cast), so it fails the test.
pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning", "ignore::UserWarning")


def test_a_signalling_nan_in_a_depth_npy_is_an_invalid_pixel_without_a_warning(tmp_path):
    from semcityloc.io.images import read_depth_file

    d = np.full((4, 5), 7.0, dtype=np.float32)
    d.view(np.uint32)[1, 2] = 0x7F800001  # a signalling NaN: casting it raises the invalid-value flag
    np.save(tmp_path / "d.npy", d)
    out = read_depth_file(tmp_path / "d.npy")
    assert out.dtype == np.float64 and np.isnan(out[1, 2]) and np.isfinite(out).sum() == 19


@pytest.fixture(scope="module")
def fuzzers(tmp_path_factory):
    work = tmp_path_factory.mktemp("fuzz")
    return {name: Fuzzer(name, work / name, real=False) for name in TARGETS}


def _no_crash(fuzzer: Fuzzer, seed: int) -> None:
    name, data = fuzzer.input(random.Random(seed))
    t0 = time.perf_counter()
    outcome, exc = fuzzer.run(name, data)
    assert outcome != CRASH, f"{fuzzer.target.name} crashed on a mutated {name}: {exc!r}"
    assert time.perf_counter() - t0 < HANG_GUARD_S, f"{fuzzer.target.name} hung on a mutated {name}"


@pytest.mark.parametrize("target", list(TARGETS))
@SLICE
@given(seed=st.integers(0, 2**32 - 1))
def test_mutated_inputs_never_crash_a_reader(fuzzers, target, seed):
    _no_crash(fuzzers[target], seed)


@pytest.mark.parametrize("target", ["citygml", "cityjson", "obj", "pose", "intrinsics", "dji"])
def test_mutated_real_files_never_crash_a_reader(target, tmp_path):
    if not SHARED_DATA.is_dir():
        pytest.skip("real data not found: ../shared/data is absent on this machine")
    fuzzer = Fuzzer(target, tmp_path)
    fuzzer.seeds = real_seeds(target)
    assert fuzzer.seeds, f"no real seed for {target} in {SHARED_DATA}"
    for name, data in fuzzer.seeds:  # the unmutated files read
        assert fuzzer.run(name, data)[0] != CRASH
    for seed in range(15):
        _no_crash(fuzzer, 1000 + seed)


@SLICE
@given(data=st.binary(max_size=300))
def test_random_bytes_are_typed_errors_for_the_image_readers(tmp_path_factory, data):
    folder = tmp_path_factory.mktemp("bytes", numbered=True)
    for name, read in (("m.png", read_mask_file), ("m.npy", read_mask_file), ("d.png", read_depth_file)):
        (folder / name).write_bytes(data)
        try:
            read(folder / name)
        except InputFileError:
            pass


# ------------------------------------------------------------------- regressions: crashes fuzzing found
def test_json_intrinsics_and_pose_with_integers_beyond_float64_are_typed(tmp_path):
    with pytest.raises(CameraError, match="'fy' is too large"):
        read_intrinsics(
            '{"fx": 1000, "fy": ' + "9" * 400 + ', "cx": 320, "cy": 256, "width": 640, "height": 512}'
        )
    with pytest.raises(PoseError, match="too large"):
        read_pose(json.dumps({"xyz": [1, 2, 10**400], "roll": 0, "pitch": 0, "yaw": 0}))


def test_intrinsics_of_an_absurd_image_size_are_typed(tmp_path):
    """An image 2**64 pixels tall (a typo or garbage in a calibration file): numpy's linspace raised a
    casting error from deep inside the lens check before (stop 48's fuzz run, seed 48)."""
    with pytest.raises(CameraError, match="height must be at most 100000 pixels"):
        read_intrinsics("1125,1125,320,256,640,18446744073709551616")
    with pytest.raises(CameraError, match="width must be at most 100000 pixels"):
        read_intrinsics(
            json.dumps({"fx": 1000, "fy": 1000, "cx": 320, "cy": 256, "width": 10**17, "height": 512})
        )
    assert read_intrinsics("1125,1125,320,256,640,512").height == 512


def test_an_exif_gps_hemisphere_that_is_no_letter_is_typed(tmp_path, monkeypatch):
    """GPSLatitudeRef holding numbers instead of "N"/"S" (stop 48's fuzz run, seed 48, a mutated DJI photo):
    an AttributeError from ``str.strip`` before; now the GPS block is unreadable, typed. Pillow will not
    write such a tag, so the photo's GPS block is given it on reading."""
    from dji_photo import dji_jpeg
    from semcityloc.datasets import dji_metadata

    path = dji_jpeg(tmp_path / "DJI_0001.JPG", gps=(-52.5, 13.4, 80.0))
    assert read_dji_metadata(path).latitude == pytest.approx(-52.5, abs=1e-6)
    real_get_ifd = Image.Exif.get_ifd

    def odd_gps(self, tag):
        ifd = real_get_ifd(self, tag)
        return {**ifd, 1: (0.5, 1.0)} if tag == 0x8825 else ifd

    monkeypatch.setattr(Image.Exif, "get_ifd", odd_gps)
    with pytest.raises(InputFileError, match="unreadable EXIF GPS block"):
        read_dji_metadata(path)
    assert dji_metadata._dms((52.0, 30.0, 0.0), b"S", "S") == -52.5  # a byte string is read as its letter


def test_colmap_ids_beyond_int64_and_colours_beyond_a_byte_are_typed(tmp_path):
    images = tmp_path / "images.txt"
    images.write_text("1 1 0 0 0 1 2 3 1 a.jpg\n100 200 18446744073709551616\n")
    with pytest.raises(InputFileError, match="line 2: point3D ids out of range"):
        read_images_text(images)
    points = tmp_path / "points3D.txt"
    points.write_text("1 1.0 2.0 3.0 -2147483649 0 0 0.5 1 0\n")
    with pytest.raises(InputFileError, match="colour values must be 0..255"):
        read_points3D_text(points)


def test_obj_face_index_beyond_int64_is_typed(tmp_path):
    path = tmp_path / "m.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 18446744073709551616\n")
    with pytest.raises(InputFileError, match="line 4"):
        read_obj(path)


def test_obj_of_a_lone_line_continuation_is_typed(tmp_path):
    """A file of one backslash (a continuation with nothing after it: atheris, stop 48): an IndexError
    before; now an OBJ with no faces, a typed answer. A continuation that joins real lines still reads."""
    path = tmp_path / "m.obj"
    for text in ("\\", "\\\n\\\n", "v 0 0 0\nv 1 0 0\nv 0 1 0\n\\"):
        path.write_text(text)
        with pytest.raises(EmptyModelError, match="no faces"):
            read_obj(path)
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 \\\n 3\nf 2 4 3\n")
    assert read_obj(path).num_triangles == 2


def _npy_header(shape, descr="<f8") -> bytes:
    header = repr({"descr": descr, "fortran_order": False, "shape": shape}).encode()
    header += b" " * (63 - (len(header) + 10) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header


def test_npy_with_a_broken_or_forged_header_is_typed_and_allocates_nothing(tmp_path):
    broken = tmp_path / "broken.npy"
    broken.write_bytes(b"\x93NUMPY\x01\x00\x10\x00{'descr': '<f8\n")  # tokenize.TokenError before
    forged = tmp_path / "forged.npy"
    forged.write_bytes(_npy_header((10**6, 10**6)) + b"\0" * 64)  # 8 TB announced, 64 bytes there
    objects = tmp_path / "objects.npy"
    objects.write_bytes(_npy_header((2,), "|O") + b"\0" * 16)
    for path, needle in ((broken, "not a readable .npy"), (forged, "truncated"), (objects, "numbers")):
        for read in (read_mask_file, read_depth_file):
            with pytest.raises(InputFileError, match=needle):
                read(path)


def test_png_with_a_broken_chunk_or_a_bomb_header_is_typed(tmp_path):
    buf = io.BytesIO()
    Image.fromarray(np.zeros((48, 64), np.uint8), mode="L").save(buf, format="PNG")
    data = bytearray(buf.getvalue())
    data[37:41] = b"W\x88\xe6\x96"  # the first chunk after IHDR: its type garbled (SyntaxError before)
    broken = tmp_path / "broken.png"
    broken.write_bytes(bytes(data))
    bomb = bytearray(buf.getvalue())
    bomb[16:24] = struct.pack(">II", 2**17, 2**16)  # IHDR: 8.6 G pixels (DecompressionBombError before)
    (tmp_path / "bomb.png").write_bytes(bytes(bomb))
    for path in (broken, tmp_path / "bomb.png"):
        for read in (read_mask_file, read_depth_file, load_image):
            with pytest.raises(InputFileError):
                read(path)


def test_cityjson_integers_beyond_float64_are_typed(tmp_path):
    doc = box_doc()
    doc["vertices"][0][0] = 10**400
    with pytest.raises(MalformedCityJSONError, match="'vertices'"):
        read_cityjson(write(tmp_path, doc))
    doc = box_doc()
    doc["transform"]["translate"][0] = 10**400
    with pytest.raises(MalformedCityJSONError, match="'transform'"):
        read_cityjson(write(tmp_path, doc))


def test_atheris_coverage_guided_smoke(tmp_path):
    """The coverage-guided engine (optional extra ``fuzz``) runs a target to its end without a crash."""
    pytest.importorskip("atheris", reason="atheris (the optional extra 'fuzz') is not installed here")
    counts = tmp_path / "counts.json"
    script = Path(__file__).with_name("fuzz_atheris.py")
    proc = subprocess.run(
        [sys.executable, "-W", "ignore", str(script), "intrinsics", "300", str(counts)],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    outcome = json.loads(counts.read_text())
    assert sum(outcome.values()) == 300 and outcome["crash"] == 0 and outcome["typed"] > 0


def test_exif_focal_length_of_the_wrong_type_is_typed(tmp_path):
    exif = Image.Exif()
    exif.get_ifd(0x8769)[37386] = (1.0, 2.0)  # a tuple where a rational belongs (TypeError before)
    path = tmp_path / "photo.jpg"
    Image.fromarray(np.zeros((48, 64, 3), np.uint8)).save(path, exif=exif.tobytes())
    with pytest.raises(InputFileError, match="unreadable EXIF focal length"):
        read_dji_metadata(path)


def test_a_pose_line_of_separators_alone_is_typed():
    with pytest.raises(PoseError):
        read_pose(",\n")  # IndexError before
    assert read_pose(",\n1,2,100,0,5,30\n").center.tolist() == pytest.approx([1, 2, 100])
