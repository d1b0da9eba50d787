"""The combined outputs of a photo run (``semcityloc run``), written once every photo is done.

Read back from the per-photo ``poses/<stem>.json`` files (so a run finished over several sessions exports
the same), in the formats users import elsewhere:

- ``colmap/``: ``cameras.txt``, ``images.txt``, ``points3D.txt`` (empty): the localized photos' poses in
  the model's frame, named by image (``datasets.colmap.write_model``, the one COLMAP writer), each with
  the camera its pose holds with (a pose the focal check re-found: a camera of its own, its focal lengths
  times the pose file's ``focal_scale``);
- ``geotags.csv`` (model CRS known): every photo's WGS 84 position and yaw, pitch, roll as Pix4D,
  Metashape and OpenDroneMap define them (``datasets.geotags``; ``source`` = ``semcityloc`` for a
  corrected pose, with its covariance's sigmas as accuracy, ``prior (not localized: ...)`` for a photo
  that keeps its prior, with the prior's uncertainty as accuracy), what Metashape and Pix4D import as
  reference positions and orientations;
- ``geo.txt`` (model CRS known): OpenDroneMap's image geolocation file of the localized photos, in the
  model's horizontal CRS (its own coordinates: no height conversion), with the covariance's horizontal and
  vertical accuracy;
- ``cameras.geojson`` (model CRS known): camera centres and ground footprints for a GIS
  (``datasets.geojson``), every photo (at its estimate, or at its prior when not localized).

Without a CRS (a model in a local frame such as UAVD4L-LoD's) the geotag files and the GeoJSON cannot be
written (their coordinates are WGS 84 or the CRS's; a GIS reads local metres as degrees): the summary says
so and names ``--crs`` / ``--offset``. A photo whose name holds white space is left out of ``colmap/`` and
``geo.txt`` (both split their lines on spaces: ``space_split_names``) with one warning; the run's other
exports and its summary are written all the same.
"""

from __future__ import annotations

import json
import math
from collections import Counter
from collections.abc import Iterable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from semcityloc.benchmark.photo_inputs import INPUT_FINGERPRINTS
from semcityloc.benchmark.results import SKIPPED, row_pose
from semcityloc.benchmark.runfiles import (
    COLMAP_DIR,
    GEOJSON_FILE,
    GEOTAGS_FILE,
    ODM_GEO_FILE,
    POSES_DIR,
    RESULTS_FILE,
)
from semcityloc.citymodel.model import CityModel
from semcityloc.classes import BUILDING_CLASSES
from semcityloc.datasets.colmap import ColmapModel, text_unreadable_names, write_model
from semcityloc.datasets.dji import GEOID_UNUSED_NOTE, HEIGHT_AS_IS_NOTE, dji_geotag
from semcityloc.datasets.geojson import CameraFeature, cameras_geojson, write_geojson
from semcityloc.datasets.geotags import GeotagRow, geotags_csv_text, odm_geo_text
from semcityloc.datasets.photos import APPROXIMATE_INTRINSICS_NOTE, INTRINSICS_35MM
from semcityloc.errors import InputFileError, SemCityLocError, counted, parameter, shown_names
from semcityloc.geometry.conventions import wrap_deg
from semcityloc.geometry.errors import center_error_m, rotation_error_deg
from semcityloc.geometry.pose import Pose
from semcityloc.geometry.pose_json import focal_scale_of, pose_from_json
from semcityloc.geometry.spec_text import labelled
from semcityloc.io.files import json_safe, write_atomic
from semcityloc.localization.covariance import horizontal_sigma
from semcityloc.localization.focal_check import found_camera
from semcityloc.localization.result import LOCALIZED, REASON_AT_EDGE

NO_CRS = (
    "the city model names no CRS, so no geotags.csv / geo.txt / cameras.geojson (their coordinates are "
    f"WGS 84 or the CRS's); pass {parameter('crs')} (and {parameter('offset')} when the model's frame is its "
    "CRS minus an offset)"
)


def position_accuracy(covariance: dict | None) -> tuple[float, float] | None:
    """(horizontal per axis, vertical) one-sigma accuracy (m) of a pose from its covariance record
    (``covariance.covariance_dict``; ``covariance.horizontal_sigma``); None without one."""
    if not covariance:
        return None
    sx, sy, sz = covariance["sigma"][:3]
    return horizontal_sigma(sx, sy), float(sz)


def ground_z(model: CityModel) -> float:
    """The model's ground height (world frame): the median lowest point of its building triangles."""
    building = np.isin(model.classes, BUILDING_CLASSES)
    tris = model.triangles[building] if building.any() else model.triangles
    z = model.vertices[tris][:, :, 2].astype(np.float64).min(1)
    return float(np.median(z) + model.origin[2]) if z.size else float(model.origin[2])


def _record_status(record: dict) -> object:
    """The status a record states (at its top level when not localized, in ``extra`` with a pose)."""
    return record.get("status", record.get("extra", {}).get("status"))


def read_record(path: Path, name: str) -> tuple[dict, Pose | None] | str:
    """Photo ``name``'s ``poses/<stem>.json``: its record and, when localized, its pose; else why it is no
    usable record (a string): missing, not JSON, no status, another photo's (a copied file), or localized
    without a pose that reads."""
    if not path.is_file():
        return "no pose file"
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        return f"unreadable ({exc})"
    if not isinstance(record, dict) or _record_status(record) is None:
        return "holds no result record"
    image = record.get("image", record.get("extra", {}).get("image"))
    if image != name:
        return f"is the record of {image!r}"
    if _record_status(record) != LOCALIZED:
        return record, None
    try:
        return record, labelled(str(path), pose_from_json, record)  # the record read above: no second read
    except SemCityLocError as exc:
        return f"localized without a pose that reads ({exc})"


def redo_remedy(count: int, results: Path, what: str = "photo") -> str:
    """How to redo ``count`` finished photos (or data-set queries: ``what``) whose rows no longer stand:
    delete the rows and run again."""
    one = count == 1
    return (
        f"delete {'its row' if one else 'their rows'} from {results} and run again to redo "
        f"{'it' if one else 'them'} (or {parameter('overwrite')}, which redoes every {what})"
    )


# A flight's priors share an offset when its localized photos moved from them alike (``prior_offset_notes``).
OFFSET_MIN_PHOTOS = 5
OFFSET_NOTE_M = 5.0  # smaller shared offsets are within what the default prior uncertainty expects
OFFSET_SPREAD_RATIO = 2.0  # the median offset at least this many times the photos' spread about it
OFFSET_SAME_SIDE = 0.9  # and at least this share of the photos moved to its side
# A shared yaw offset: at least the default yaw sigma (``PriorUncertainty``: 3 deg), same rules otherwise.
OFFSET_NOTE_DEG = 3.0


def shared_height_offset(moves: np.ndarray) -> tuple[float, float] | None:
    """(median, robust spread) of the photos' height moves (``moves``: ``(n, 3)``, estimate minus prior
    centre, z up) when they share an offset by the rules of ``prior_offset_notes``; None otherwise."""
    dz = np.asarray(moves, dtype=np.float64).reshape(-1, 3)[:, 2]
    if len(dz) < OFFSET_MIN_PHOTOS:
        return None
    median = float(np.median(dz))
    spread = 1.4826 * float(np.median(np.abs(dz - median)))
    same_side = float(np.mean(np.sign(dz) == np.sign(median)))
    shared = abs(median) >= max(OFFSET_NOTE_M, OFFSET_SPREAD_RATIO * spread) and same_side >= OFFSET_SAME_SIDE
    return (median, spread) if shared else None


def shared_horizontal_offset(moves: np.ndarray) -> tuple[np.ndarray, float] | None:
    """(median x/y move, robust spread about it) when the photos share a horizontal offset by the rules
    of ``prior_offset_notes``; None otherwise."""
    xy = np.asarray(moves, dtype=np.float64).reshape(-1, 3)[:, :2]
    if len(xy) < OFFSET_MIN_PHOTOS:
        return None
    median = np.median(xy, axis=0)
    spread = 1.4826 * float(np.median(np.linalg.norm(xy - median, axis=1)))
    shift = float(np.linalg.norm(median))
    same_side = float(np.mean(xy @ median > 0))
    shared = shift >= max(OFFSET_NOTE_M, OFFSET_SPREAD_RATIO * spread) and same_side >= OFFSET_SAME_SIDE
    return (median, spread) if shared else None


def offset_sigma(moves: np.ndarray, yaw_moves: np.ndarray) -> dict[str, int]:
    """Per ``--prior-sigma`` key, the sigma whose 3 sigma covers a shared offset of the priors and twice
    the photos' spread about it (only the axes with such an offset)."""
    asked = {}
    if (height := shared_height_offset(moves)) is not None:
        asked["z"] = math.ceil((abs(height[0]) + 2.0 * height[1]) / 3.0)
    if (horizontal := shared_horizontal_offset(moves)) is not None:
        asked["xy"] = math.ceil((float(np.max(np.abs(horizontal[0]))) + 2.0 * horizontal[1]) / 3.0)
    if (yaw := shared_yaw_offset(yaw_moves)) is not None:
        asked["yaw"] = math.ceil((abs(yaw[0]) + 2.0 * yaw[1]) / 3.0)
    return asked


def prior_offset_notes(
    moves: np.ndarray, at_edge: int = 0, at_edge_xy: int = 0, asked: dict[str, int] | None = None
) -> list[str]:
    """What the localized photos' moves from their priors (``(n, 3)``: estimate minus prior centre, in the
    model's frame, z up) say about the priors as a whole: a note when they share a height or horizontal
    offset of at least ``OFFSET_NOTE_M`` that stands out of their spread (the robust spread, 1.4826 x the
    median distance from the median, times ``OFFSET_SPREAD_RATIO``) and that ``OFFSET_SAME_SIDE`` of them
    moved towards; at least ``OFFSET_MIN_PHOTOS`` photos. Independent priors as wide as the defaults (height
    uniform +-30 m, 2-15 m horizontally) get the height note for 3 % of 5-photo sets, 0.5 % of 10-photo
    sets and none of 30 (5,000 simulated sets each); a shared 20 m height offset with 2 / 5 / 8 m of
    scatter gets it in 100 / 99 / 82 % of 10-photo sets. Why: one photo's prior 20 m off in
    height is GNSS noise; a whole flight's is a height reference (geoid, take-off altitude) the user can
    fix, and then the photos refused at the search volume's edge localize too. ``at_edge``: how many
    photos were refused at its height edge; the height note then names the ``--prior-sigma z=`` for a run
    again as it is: ``asked["z"]`` (``rerun_sigma``: the same figure the run's other notes name), else the
    one whose 3 sigma covers the offset and twice the spread (``offset_sigma``). ``at_edge_xy``: the same
    for the horizontal edges and note (``xy=``, covering the offset's larger axis)."""
    moves = np.asarray(moves, dtype=np.float64).reshape(-1, 3)
    own = offset_sigma(moves, np.zeros(0))
    asked = {**own, **(asked or {})}
    notes = []
    if (height := shared_height_offset(moves)) is not None:
        median_z, spread_z = height
        notes.append(
            f"the {len(moves)} localized photos sit a median {abs(median_z):.1f} m "
            f"{'below' if median_z < 0 else 'above'} their priors (spread {spread_z:.1f} m): the priors "
            "share a height offset, most often the height reference (geoid, take-off altitude; "
            "docs/your-data.md, sections 2 and 8); photos refused at the search volume's edge may "
            "localize once it is fixed"
            + (
                f" ({counted(at_edge, 'was', 'were')}; or run again with "
                f"{parameter('run_prior_sigma', 'z=' + str(asked['z']))})"
                if at_edge
                else ""
            )
        )
    if (horizontal := shared_horizontal_offset(moves)) is not None:
        median_xy, spread_xy = horizontal
        notes.append(
            f"the {len(moves)} localized photos sit a median {float(np.linalg.norm(median_xy)):.1f} m from "
            f"their priors horizontally (x {median_xy[0]:+.1f} m, y {median_xy[1]:+.1f} m in the model's "
            f"frame; spread {spread_xy:.1f} m): the priors share a horizontal offset (a wrong "
            f"{parameter('crs')} or {parameter('offset')}, or a GNSS bias)"
            + (
                f"; {counted(at_edge_xy, 'photo was', 'photos were')} refused at the search volume's "
                "horizontal edge: run again with "
                f"{parameter('run_prior_sigma', 'xy=' + str(asked['xy']))}"
                if at_edge_xy
                else ""
            )
        )
    return notes


def _heading_known(inp) -> bool:
    return inp.prior is None or inp.prior.heading_known


def no_heading_notes(names: list[str]) -> list[str]:
    """One note naming the photos whose prior had no heading (a DJI photo without ``GimbalYawDegree``, a
    geotag row without a yaw): every heading was searched for them, about four times a headed search's time,
    and their yaw 0 is left out of the compass notes (``prior_yaw_notes``). Said once per run, not only in
    each photo's row."""
    if not names:
        return []
    shown = shown_names(names)
    return [
        f"{counted(len(names), 'photo')} without a heading in the prior ({shown}): every heading was "
        "searched (slower), and the yaw taken is left out of the compass notes; give the heading where "
        "it is known"
    ]


def yaw_moves_deg(estimates: list[Pose], priors: list[Pose]) -> np.ndarray:
    """(n,) estimate minus prior yaw of each photo in degrees, wrapped to (-180, 180] (``wrap_deg``): the
    turn about the vertical (counter-clockwise seen from above) that took each prior's heading to the found
    one."""
    if not estimates:
        return np.zeros(0)
    found = Pose.stack(estimates).to_xyz_rpy()[:, 5]
    prior = Pose.stack(priors).to_xyz_rpy()[:, 5]
    return wrap_deg(found - prior)


def shared_yaw_offset(moves_deg: np.ndarray) -> tuple[float, float] | None:
    """(median, robust spread) of the photos' yaw moves (``yaw_moves_deg``) when they share an offset of
    at least ``OFFSET_NOTE_DEG`` by the rules of ``prior_offset_notes``; None otherwise."""
    moves = np.asarray(moves_deg, dtype=np.float64).reshape(-1)
    if len(moves) < OFFSET_MIN_PHOTOS:
        return None
    median = float(np.median(moves))
    spread = 1.4826 * float(np.median(np.abs(moves - median)))
    same_side = float(np.mean(np.sign(moves) == np.sign(median)))
    shared = (
        abs(median) >= max(OFFSET_NOTE_DEG, OFFSET_SPREAD_RATIO * spread) and same_side >= OFFSET_SAME_SIDE
    )
    return (median, spread) if shared else None


def prior_yaw_notes(
    moves_deg: np.ndarray, at_edge: int = 0, asked: dict[str, int] | None = None
) -> list[str]:
    """A note when the localized photos' yaw moves from their priors (``yaw_moves_deg``) share an offset
    (``shared_yaw_offset``). Why: one photo's compass 5 deg off is noise; a whole flight's is a compass
    bias, or a heading read from the aircraft (``FlightYawDegree``) where the gimbal's was meant, and the
    photos it pushed beyond the search volume's yaw edge (``at_edge`` of them) localize with a wider
    stated yaw uncertainty, which the note then names: ``asked["yaw"]`` when given (``rerun_sigma``), else
    the one whose 3 sigma covers the offset and twice the spread."""
    yaw = shared_yaw_offset(moves_deg)
    if yaw is None:
        return []
    median, spread = yaw
    asked = {**offset_sigma(np.zeros((0, 3)), moves_deg), **(asked or {})}
    return [
        f"the {len(np.ravel(moves_deg))} localized photos are turned a median {abs(median):.1f} deg "
        f"{'counter-clockwise' if median > 0 else 'clockwise'} (seen from above) from their priors' yaw "
        f"(spread {spread:.1f} deg): the priors share a yaw offset, a compass bias or the aircraft's heading "
        "taken for the gimbal's (docs/your-data.md, section 3)"
        + (
            f"; {counted(at_edge, 'photo was', 'photos were')} refused at the search volume's yaw edge: run "
            f"again with {parameter('run_prior_sigma', 'yaw=' + str(asked['yaw']))}"
            if at_edge
            else ""
        )
    ]


def _edge_search(record: dict) -> dict | None:
    """The ``search`` record of a photo refused at the search volume's edge (``at_edge``: its edges, e.g.
    ``["z-"]``; ``edge_sigma``: the sigmas its warning names); None for any other photo."""
    return (record.get("search") or {}) if record.get("reason") == REASON_AT_EDGE else None


def edge_count(records: list[dict], *axes: str) -> int:
    """How many photo records were refused at the search volume's edge along any of ``axes`` (``"x"``,
    ``"y"``, ``"z"``, ``"yaw"``)."""
    searches = [s for s in map(_edge_search, records) if s is not None]
    return sum(any(edge.rstrip("+-") in axes for edge in s.get("at_edge", [])) for s in searches)


def refused_edge_sigma(records: list[dict]) -> dict[str, int]:
    """Per ``--prior-sigma`` key, the widest sigma that the photos refused at the search volume's edge ask
    for (``search.edge_sigma``, what each photo's warning names)."""
    sigma: dict[str, int] = {}
    for search in filter(None, map(_edge_search, records)):
        for axis, value in (search.get("edge_sigma") or {}).items():
            sigma[axis] = max(sigma.get(axis, 0), int(value))
    return sigma


def rerun_sigma(records: list[dict], moves: np.ndarray, yaw_moves: np.ndarray) -> dict[str, int]:
    """The one ``--prior-sigma`` that a run's notes name for a run again: per axis on which photos were
    refused at the search volume's edge, the larger of what their warnings ask for
    (``refused_edge_sigma``) and what the priors' shared offset asks for (``offset_sigma``). Both notes
    about the same refusals (the offset's and the edge's) then name the same figure."""
    edge = refused_edge_sigma(records)
    offset = offset_sigma(moves, yaw_moves)
    return {axis: max(value, offset.get(axis, 0)) for axis, value in edge.items()}


def edge_notes(records: list[dict], asked: dict[str, int] | None = None) -> list[str]:
    """One note for the photos refused at the search volume's edge: how many at each edge, and the
    ``--prior-sigma`` that covers them all: per axis the widest their warnings ask for
    (``refused_edge_sigma``), or ``asked`` (``rerun_sigma``) where that is wider."""
    refused = [s for s in map(_edge_search, records) if s is not None]
    if not refused:
        return []
    edges = Counter(e for s in refused for e in s.get("at_edge", []))
    sigma = refused_edge_sigma(records)
    sigma = {axis: max(value, (asked or {}).get(axis, 0)) for axis, value in sigma.items()}
    where = ", ".join(f"{e}: {n}" for e, n in sorted(edges.items()))
    ask = ",".join(f"{a}={sigma[a]}" for a in ("xy", "z", "yaw") if a in sigma)
    count = f"{len(refused)} {'photo was' if len(refused) == 1 else 'photos were'}"
    return [
        f"{count} refused at the search volume's edge ({where or 'edges not recorded'}): "
        "their priors are further off than stated"
        + (
            f"; run again with {parameter('run_prior_sigma', ask)} to cover all of them, or correct the "
            "priors"
            if ask
            else ""
        )
    ]


def beyond_notes(records: list[dict]) -> list[str]:
    """One note for the refused photos for which a view beyond the searched volume scored higher than any
    inside (``search.beyond.higher``, ``cascade.look_beyond``): their priors may be further off
    horizontally than stated; the ``--prior-sigma xy`` that searches past the farthest such view."""
    hinted = [
        r["search"]["beyond"]
        for r in records
        if r.get("status") != LOCALIZED and ((r.get("search") or {}).get("beyond") or {}).get("higher")
    ]
    if not hinted:
        return []
    xy = max(int((b.get("sigma") or {}).get("xy", 0)) for b in hinted)
    count = f"{len(hinted)} refused {'photo has' if len(hinted) == 1 else 'photos have'}"
    return [
        f"{count} a view beyond the searched volume that matches better than any inside: if their priors "
        "may be further off horizontally than stated"
        + (
            f", run again with {parameter('run_prior_sigma', 'xy=' + str(xy))}"
            if xy
            else f", state a larger horizontal sigma ({parameter('run_prior_sigma', 'xy=...')})"
        )
        + " (a map that differs from the world in view can do the same)"
    ]


def focal_notes(inputs: list) -> list[str]:
    """One line per camera whose focal length the flight estimated, or tried to (``calibrate_focal``)."""
    estimates = [inp.focal_estimate for inp in inputs if inp.focal_estimate is not None]
    counts = Counter(json.dumps(est, sort_keys=True) for est in estimates)
    notes: dict[str, None] = {}
    for est in estimates:
        count = counts[json.dumps(est, sort_keys=True)]
        if est.get("scale") is not None:
            line = (
                f"the focal length of {counted(count, 'photo')} was estimated from {est['images']} oblique "
                "ones: "
                f"{est['scale']:.4f} x the stated one (poses/<stem>.json: focal_estimate)"
            )
        else:
            line = (
                f"the focal length of {counted(count, 'photo')} could not be estimated: {est.get('reason')}"
            )
        notes[line] = None
    return list(notes)


def space_split_names(names: list[str]) -> list[str]:
    """The ``names`` that COLMAP's ``images.txt`` and OpenDroneMap's ``geo.txt`` cannot hold: both split a
    line on white space (``datasets.colmap.text_unreadable_names``; ODM takes the first token as the name),
    so a name holding any would read back as another photo's, or as none. Why a list: ``write_exports``
    leaves them out of those two files with one warning instead of losing the run's exports to one legal
    file name."""
    return text_unreadable_names(names)


def left_out_warning(names: list[str], files: list[str]) -> list[str]:
    """One warning naming the localized photos left out of ``files`` (``space_split_names``), and where
    their poses are; none when there are none."""
    if not names:
        return []
    return [
        f"{counted(len(names), 'localized photo')} left out of {' and '.join(files)} (their readers split a "
        f"line on spaces: a name holding one would read back cut short): {shown_names(names)}; the poses are "
        f"in {POSES_DIR}/ and the other exports (rename such photos without spaces to have them there too)"
    ]


def check_records(out_dir: Path, inputs: list) -> tuple[dict[str, dict], dict[str, Pose]]:
    """Every finished photo's record and, of the localized, its pose (``read_record``); refused in one line
    when one has no usable ``poses/<stem>.json`` (every one of ``inputs`` has its row in ``results.csv``
    when the exports are written): its record (covariance, search, prior) is not in the row, so the exports
    would lack it (COLMAP without it, the GeoJSON and geotags at its prior as "no result") while the summary
    counts it. Deleting its row redoes it."""
    records, estimates, problems = {}, {}, {}
    for inp in inputs:
        got = read_record(out_dir / POSES_DIR / f"{inp.stem}.json", inp.name)
        if isinstance(got, str):
            problems[f"{inp.stem}.json"] = got
            continue
        records[inp.name], pose = got
        if pose is not None:
            estimates[inp.name] = pose
    if problems:
        shown = shown_names([f"{name}: {why}" for name, why in problems.items()])
        count = f"{len(problems)} finished {'photo has' if len(problems) == 1 else 'photos have'}"
        raise InputFileError(
            f"{out_dir / POSES_DIR}: {count} no usable pose file ({shown}), so no exports were written; "
            + redo_remedy(len(problems), out_dir / RESULTS_FILE)
        )
    return records, estimates


# A finished row's prior or truth this far from the current file's (m, deg) was made from another file.
CHANGED_INPUT_M, CHANGED_INPUT_DEG = 1e-3, 1e-3


def changed_inputs(rows: list[dict[str, str]], inputs: list, model: CityModel) -> dict[str, str]:
    """``{photo: what changed}`` for finished rows whose prior or ground truth is no longer what the
    current files say, or whose photo, mask or depth file is no longer the one the row was made from
    (``changed_files``) (``inputs``: ``photo_inputs.PhotoInput`` by row index). Why: a resume keeps finished
    rows, so a corrected ``--truth`` (or a replaced prior) would leave the old errors in the rows and the
    summary, and a corrected mask the old pose (or a ``skipped`` row the fixed file never ran), silently;
    what a row was made from is in its own columns, so it is compared, not trusted."""
    changed = {}
    for row in rows:
        index = int(row["index"])
        if index >= len(inputs):
            continue
        inp = inputs[index]
        why = _moved_pose(row, inp, model) if row.get("status") != SKIPPED else None
        why = why or changed_files(row, inp.fingerprints(), inp.later_kinds())
        if why:
            changed[inp.name] = why
    return changed


def _moved_pose(row: dict[str, str], inp, model: CityModel) -> str | None:
    """How the photo's prior or truth differs from the one its row was made from; None when neither does."""
    prior = inp.prior.pose_world if inp.prior is not None else None
    for what, now_world, prefix in (("prior", prior, "prior"), ("truth", inp.truth_world, "true")):
        then = row_pose(row, prefix)
        now = model.pose_to_local(now_world) if now_world is not None else None
        if then is None and now is None:
            continue
        if then is None or now is None:
            return f"its {what} was {'added' if then is None else 'removed'}"
        moved = float(center_error_m(now, then))
        turned = float(rotation_error_deg(now, then))
        if moved > CHANGED_INPUT_M or turned > CHANGED_INPUT_DEG:
            return f"its {what} moved {moved:.3g} m, turned {turned:.3g} deg"
    return None


def row_fingerprints(row: dict[str, str]) -> dict | None:
    """The fingerprints of the files a row was made from (``PhotoInput.fingerprints``, in its
    ``meta_json``); None for a row written before they were kept (stop 52), which is not compared."""
    try:
        meta = json.loads(row.get("meta_json") or "{}")
    except ValueError:
        return None
    found = meta.get(INPUT_FINGERPRINTS) if isinstance(meta, dict) else None
    return found if isinstance(found, dict) else None


def _file_name(*fingerprints: object) -> str:
    """`` <file name>`` of the first of ``fingerprints`` that names one, for a message; else empty."""
    names = [f["file"] for f in fingerprints if isinstance(f, dict) and f.get("file")]
    return f" {names[0]}" if names else ""


def _content(fingerprint: object) -> tuple | None:
    """(size, SHA-256) of a fingerprint; None for a file that did not read."""
    return (fingerprint.get("bytes"), fingerprint.get("sha256")) if isinstance(fingerprint, dict) else None


# The kinds of files a row is made from, in the order a change is told (``changed_files``).
FINGERPRINT_KINDS = ("photo", "mask", "depth", "intrinsics")


def changed_files(row: dict[str, str], now: dict[str, dict | None], later: Iterable[str] = ()) -> str | None:
    """How the files a row was made from (``FINGERPRINT_KINDS``; a photo's ``PhotoInput.fingerprints``, a
    data set's mask and depth: size and SHA-256 of the bytes) differ from them as they are now (``now``);
    None when they are the same, or when the row kept no fingerprints (``row_fingerprints``). ``later``: the
    kinds fingerprinted since stop 53 (an intrinsics file, a backend's mask and depth), which a row of an
    earlier version lacks: not compared for it. By content, not by modification time: a file copied or
    checked out with the same bytes is the same, one restored with ``cp -p`` or ``git checkout`` with other
    bytes is not."""
    then = row_fingerprints(row)
    if then is None:
        return None
    for kind in FINGERPRINT_KINDS:
        if (kind not in then and kind not in now) or (kind not in then and kind in later):
            continue
        name = _file_name(now.get(kind), then.get(kind))
        if kind not in then or kind not in now:
            return f"its {kind}{name} was {'added' if kind not in then else 'removed'}"
        before, after = _content(then[kind]), _content(now[kind])
        if before == after:
            continue
        if before is None or after is None:
            return f"its {kind}{name} {'reads now' if before is None else 'no longer reads'}"
        sizes = "same size" if before[0] == after[0] else f"{before[0]} -> {after[0]} bytes"
        return f"its {kind}{name} changed ({sizes})"
    return None


def unfingerprinted(rows: list[dict[str, str]], inputs: list | None = None) -> int:
    """How many of ``rows`` kept no fingerprints of their files (``row_fingerprints``: written before
    stop 52), or none of a kind their photo has now that was fingerprinted later (``inputs``:
    ``PhotoInput`` by row index, ``PhotoInput.later_kinds``: before stop 53): a file changed since is not
    noticed for them."""
    count = 0
    for row in rows:
        then, index = row_fingerprints(row), int(row["index"])
        later = inputs[index].later_kinds() if inputs is not None and index < len(inputs) else set()
        count += then is None or not later <= set(then)
    return count


def _found(inp, records: dict[str, dict]):
    """The camera ``inp``'s estimate holds with: its focal lengths times its pose file's ``focal_scale``
    (``pose_json.focal_scale_of``: where the focal check's correction re-found the pose; a camera of its own
    in ``colmap/cameras.txt`` then)."""
    return found_camera(inp.camera, focal_scale_of(records[inp.name]))


def camera_features(
    inputs: list, records: dict[str, dict], estimates: dict[str, Pose], shift: np.ndarray
) -> list[CameraFeature]:
    """Every photo of ``inputs`` for ``cameras.geojson``: at its estimate when localized, else at its
    prior, with its status, position in the CRS, shift from the prior and (with a truth) error."""
    features = []
    for inp in inputs:
        est = estimates.get(inp.name)
        pose = est if est is not None else inp.prior.pose_world
        reason = records[inp.name].get("reason") or "no result"
        props = {
            "status": LOCALIZED if est is not None else f"not localized: {reason}",
            "pose": "semcityloc estimate" if est is not None else "prior",
            "position": (pose.center + shift).tolist(),
            "prior_shift_m": float(center_error_m(est, inp.prior.pose_world)) if est is not None else None,
        }
        if inp.truth_world is not None and est is not None:
            props["error_m"] = float(center_error_m(est, inp.truth_world))
        camera = _found(inp, records) if est is not None else inp.camera
        features.append(CameraFeature(inp.name, camera, pose, json_safe(props)))
    return features


def write_exports(
    out_dir: Path,
    model: CityModel,
    inputs: list,
    offset: np.ndarray | None,
    target_height: str,
    geoid_separation_m: float | None = None,
) -> dict[str, Any]:
    """Write the exports (module docstring) of ``inputs`` (``photo_inputs.PhotoInput``); returns
    ``{output: path or None}``, and ``notes`` and ``warnings`` for the summary. ``target_height`` and
    ``geoid_separation_m``: what the priors were brought in with (the geotags' heights go back the same
    way)."""
    out_dir = Path(out_dir)
    shift = np.zeros(3) if offset is None else np.asarray(offset, dtype=np.float64)
    records, estimates = check_records(out_dir, inputs)
    outputs: dict[str, Any] = {"poses": str(out_dir / POSES_DIR), "notes": []}
    for inp in inputs:  # how the priors' heights were treated, said once for the run
        details = inp.prior.details
        said = [
            details.get("vertical_flag"),
            *(n for n in details.get("notes", []) if n in (HEIGHT_AS_IS_NOTE, GEOID_UNUSED_NOTE)),
        ]
        outputs["notes"] += [n for n in said if n and n not in outputs["notes"]]

    outputs["notes"] += focal_notes(inputs)
    turned = [inp.name for inp in inputs if inp.mask is not None and inp.orientation != 1]
    if turned:
        outputs["notes"].append(
            f"{counted(len(turned), 'photo carries', 'photos carry')} an EXIF orientation other than 1 "
            "(viewers turn or flip them): "
            "their masks and depth were taken as of the stored pixels, as the photo's calibration and "
            "gimbal angles are; masks made of the turned photo give wrong poses"
        )
    approximate = [
        inp.name
        for inp in inputs
        if inp.intrinsics_source == INTRINSICS_35MM and (inp.focal_estimate or {}).get("scale") is None
    ]
    if approximate:
        has = "has" if len(approximate) == 1 else "have"
        count = f"{len(approximate)} of {counted(len(inputs), 'photo')} {has} no calibrated intrinsics"
        outputs["notes"].append(f"{count}: {APPROXIMATE_INTRINSICS_NOTE}")
    found = [inp for inp in inputs if inp.name in estimates]
    moves = [estimates[inp.name].center - inp.prior.pose_world.center for inp in found]
    done = list(records.values())
    headed = [inp for inp in found if _heading_known(inp)]  # a yaw taken as 0 says nothing of a compass
    yaw_moves = yaw_moves_deg([estimates[i.name] for i in headed], [i.prior.pose_world for i in headed])
    outputs["notes"] += no_heading_notes([inp.name for inp in inputs if not _heading_known(inp)])
    asked = rerun_sigma(done, np.array(moves), yaw_moves)  # one figure per axis in every note below
    z_edge, xy_edge = edge_count(done, "z"), edge_count(done, "x", "y")
    outputs["notes"] += prior_offset_notes(np.array(moves), z_edge, xy_edge, asked)
    outputs["notes"] += prior_yaw_notes(yaw_moves, edge_count(done, "yaw"), asked)
    outputs["notes"] += edge_notes(done, asked)
    outputs["notes"] += beyond_notes(done)
    split = space_split_names([inp.name for inp in found])  # left out of images.txt and geo.txt
    cameras = {
        inp.name: (_found(inp, records), estimates[inp.name]) for inp in found if inp.name not in split
    }
    lenses = {inp.name: inp.distortion for inp in inputs}  # the photos as they are: with their lens
    colmap = ColmapModel.from_poses(cameras, lenses)
    outputs["colmap"] = str(write_model(colmap, out_dir / COLMAP_DIR, ext=".txt"))
    files = [f"{COLMAP_DIR}/images.txt"] + ([ODM_GEO_FILE] if model.crs is not None else [])
    outputs["warnings"] = left_out_warning(split, files)
    # ODM reads a geo.txt line that starts with '#' as a comment: a photo so named would lose its place there
    hashed = [inp.name for inp in found if inp.name.startswith("#") and inp.name not in split]
    if hashed and model.crs is not None:
        outputs["warnings"].append(
            f"{counted(len(hashed), 'localized photo')} left out of {ODM_GEO_FILE} (OpenDroneMap reads a "
            f"line starting with '#' as a comment): {shown_names(hashed)}; the other exports hold them"
        )
    not_in_geo_txt = set(split + hashed)

    if model.crs is None:
        outputs["geotags"] = outputs["geo_txt"] = outputs["geojson"] = None
        (out_dir / GEOJSON_FILE).unlink(missing_ok=True)  # an older version's, in local metres
        outputs["notes"].append(NO_CRS)
        return outputs
    features = camera_features(inputs, records, estimates, shift)
    collection = cameras_geojson(features, model.crs, ground_z(model), shift)
    outputs["geojson"] = str(write_geojson(collection, out_dir / GEOJSON_FILE))
    rows, odm, odm_accuracy = [], [], []
    for inp in inputs:
        est = estimates.get(inp.name)
        if est is not None:
            tag = dji_geotag(est, model.crs, shift, target_height, geoid_separation_m)
            accuracy = position_accuracy(records[inp.name].get("extra", {}).get("covariance"))
            rows.append(GeotagRow(inp.name, tag, *(accuracy or (None, None)), source="semcityloc"))
            if inp.name not in not_in_geo_txt:
                odm.append((inp.name, tuple((est.center + shift).tolist()), tag))
                odm_accuracy.append(accuracy)
        else:
            tag = dji_geotag(inp.prior.pose_world, model.crs, shift, target_height, geoid_separation_m)
            if not inp.prior.heading_known:  # its yaw 0 was taken, not known: none written
                tag = replace(tag, heading_known=False)
            reason = records[inp.name].get("reason") or "no result"
            sigma = inp.uncertainty
            rows.append(GeotagRow(inp.name, tag, sigma.xy_m, sigma.z_m, f"prior (not localized: {reason})"))
        if tag.vertical_flag and tag.vertical_flag not in outputs["notes"]:
            outputs["notes"].append(tag.vertical_flag)
    write_atomic(out_dir / GEOTAGS_FILE, geotags_csv_text(rows))
    outputs["geotags"] = str(out_dir / GEOTAGS_FILE)
    write_atomic(out_dir / ODM_GEO_FILE, odm_geo_text(model.crs, odm, odm_accuracy))
    outputs["geo_txt"] = str(out_dir / ODM_GEO_FILE)
    return outputs
