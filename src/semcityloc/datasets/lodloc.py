"""Read (and write) data sets in LoD-Loc's layout: UAVD4L-LoD, Swiss-EPFL and the LoD-Loc demo folder.

Why: LoD-Loc (v1/v2/v3) is the reference for localization against LoD models and its data sets are what
users arrive with. This module turns such a folder into ``LodLocQuery`` records (image, ``Camera``, ground
truth and prior ``Pose`` in one metric, z-up world frame) plus the path of the LoD model, so the
localizer, the renderer and the benchmark never see the layout.

Layout (one *scene* folder; a data set folder holds several scenes as sub-folders)::

    <scene>/Query_image/<name>                       the query images (.JPG, .jpg, .png, ...)
    <scene>/GT_pose/<stem>_pose.txt                  4x4 camera-to-world, OpenCV camera axes
    <scene>/GPS_pose/<stem>_pose.txt                 the sensor prior, same form
    <scene>/intrinsic/<stem>_intrinsic.txt           3x4 [K|0] (no image size: taken from the image)
    <scene>/GT_pose.txt, <scene>/GPS_pose.txt        alternative: 'name qw qx qy qz tx ty tz' lines,
                                                     world-to-camera (COLMAP); 'query/<name>' allowed
    <scene>/intrinsic.txt                            alternative: 'name PINHOLE w h fx fy cx cy' lines
    <scene>/Points_GT/<stem>_points.npy              LoD-Loc's visible-edge points (kept as a path)
    split/<file>.json                                {"train"|"val"|"test": {scene: [names]}}
    <scene>/*.obj or <scene>/../*.obj                the LoD model, same frame (or --city)

Per-image files win over the scene-level text files; when both give a pose for the same image and they
disagree by more than ``TEXT_FILE_TOLERANCE_M`` the data set records a warning (a frame mix-up).

Frames: UAVD4L-LoD's frame is a projected CRS (CGCS2000 / 3-degree Gauss-Kruger CM 114E in LoD-Loc's
``Read_EXIF.py``) minus an unpublished offset, z up: it is used as it is. Swiss-EPFL's is ECEF minus an
origin (LoD-Loc's ``trans_obj_coor.py``: lat 46.5191, lon 6.5668, h 390 m): z is not up. ``frame="auto"``
tests the model (``detect_vertical``): LoD walls are vertical, so most of the steep area of a z-up model
has a normal perpendicular to z. A model that fails the test raises ``InputFileError`` asking for
``frame="ecef"`` (and ``ecef_origin_llh`` for another data set than Swiss-EPFL). With ``frame="ecef"``
every pose and the model are rotated into the local ENU tangent frame at the ECEF origin
(x east, y north, z up; ``enu_from_ecef``): a rotation only, so distances and angles are unchanged; the
tangent plane is 0.3 m below the ellipsoid 2 km away, which a localizer working in that frame never sees.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from semcityloc.citymodel.builder import UNLABELLED, MeshBuilder
from semcityloc.citymodel.io import load_city_model
from semcityloc.citymodel.model import CityModel, ParseStats
from semcityloc.citymodel.pose_crs import camera_far_from_model
from semcityloc.errors import (
    InputFileError,
    IntrinsicsMismatchError,
    SemCityLocError,
    parameter,
    unknown_choice,
)
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.conventions import colmap_qvec_tvec
from semcityloc.geometry.intrinsics_files import read_intrinsics
from semcityloc.geometry.pose import Pose
from semcityloc.geometry.pose_files import read_pose, read_poses
from semcityloc.io.files import write_atomic
from semcityloc.io.images import image_size

IMAGE_DIR = "Query_image"
GT_DIR, PRIOR_DIR, INTRINSIC_DIR, POINTS_DIR = "GT_pose", "GPS_pose", "intrinsic", "Points_GT"
GT_TEXT, PRIOR_TEXT, INTRINSIC_TEXT = "GT_pose.txt", "GPS_pose.txt", "intrinsic.txt"
IMAGE_SUFFIXES = frozenset({".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp"})

FRAME_AUTO, FRAME_Z_UP, FRAME_ECEF = "auto", "z-up", "ecef"
FRAMES = (FRAME_AUTO, FRAME_Z_UP, FRAME_ECEF)
# Swiss-EPFL's ECEF origin (LoD-Loc script/trans_obj_coor.py, get_ecef_origin): latitude, longitude, h.
SWISS_EPFL_ECEF_ORIGIN_LLH = (46.5191, 6.5668, 390.0)

# A face is "vertical" for the frame test when its normal is within this angle of horizontal.
VERTICAL_TOLERANCE_DEG = 3.0
# Faces steeper than this (normal more than 45 deg from up) are the ones the frame test looks at.
STEEP_MIN_DEG = 45.0
# A z-up LoD model has at least this share of its steep area vertical (measured: UAVD4L-LoD1 0.99).
MIN_VERTICAL_SHARE = 0.6
# How a query left out for its intrinsics is said among the data set's warnings (``LodLocDataset.warnings``).
SKIPPED = "; skipped"
# Per-image pose file vs the scene text file: disagreement beyond this (metres) is reported.
TEXT_FILE_TOLERANCE_M = 0.01


@dataclass
class LodLocQuery:
    """One query image of a LoD-Loc data set, poses in the data set's (z-up) world frame."""

    name: str  # image file name, e.g. "DJI_20230513163714_0033_T.JPG"
    scene: str
    camera: Camera
    image_path: Path | None = None
    gt_pose_world: Pose | None = None  # cam_from_world, data set's world frame (not a model's local one)
    prior_pose_world: Pose | None = None  # cam_from_world, same frame (LoD-Loc's "GPS" prior)
    points_path: Path | None = None  # Points_GT/<stem>_points.npy when present
    gt_pose_file: Path | None = None  # the file each pose was read from (per-image file or scene text file)
    prior_pose_file: Path | None = None

    @property
    def stem(self) -> str:
        """The image name without folder and suffix: how masks and depth files are matched to it."""
        return Path(self.name).stem

    def far_pose(self, model: CityModel) -> str | None:
        """Why this query's GT pose or prior cannot be a view of ``model`` (in the model's frame, the data
        set's: ``LodLocDataset.load_model``), naming the photo and the pose file, or None: a camera farther
        from the model than a local frame reaches (``citymodel.pose_crs.camera_far_from_model``), a pose in
        another CRS. The data-set commands skip such a query with this warning; the others run."""
        poses = ((self.gt_pose_world, self.gt_pose_file), (self.prior_pose_world, self.prior_pose_file))
        for pose, file in poses:
            if pose is not None and (problem := camera_far_from_model(model.pose_to_local(pose), model)):
                return f"{self.name}: {file}: {problem}"
        return None


@dataclass
class LodLocDataset:
    """Queries of one or more scenes, the model file and how the frame was decided."""

    root: Path
    queries: list[LodLocQuery]
    model_path: Path | None
    frame: str  # FRAME_Z_UP, or FRAME_ECEF when the data was rotated into ENU
    frame_note: str
    ecef_origin_llh: tuple[float, float, float] | None = None
    warnings: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.queries)

    def query(self, name: str) -> LodLocQuery:
        """The query called ``name`` (file name or stem)."""
        for q in self.queries:
            if name in (q.name, q.stem):
                return q
        raise InputFileError(
            f"{self.root}: no query {name!r} (have {', '.join(q.name for q in self.queries[:3])})"
        )

    def load_model(self, cache: bool = True) -> CityModel:
        """The LoD model in the queries' frame (rotated into ENU for ``frame="ecef"``)."""
        if self.model_path is None:
            raise InputFileError(
                f"{self.root}: no LoD model found beside the data set; pass the model file "
                f"({parameter('city')})"
            )

        model = load_city_model(self.model_path, cache=cache)
        if self.frame == FRAME_ECEF:
            model = rotate_model(model, enu_from_ecef(*(self.ecef_origin_llh or SWISS_EPFL_ECEF_ORIGIN_LLH)))
        return model


# ---------------------------------------------------------------------------------------------- frames
def enu_from_ecef(lat_deg: float, lon_deg: float, height_m: float = 0.0) -> np.ndarray:
    """(3, 3) rotation whose rows are east, north, up at a geodetic point (WGS 84): ``enu = R @ d_ecef``."""
    for name, v in (("latitude", lat_deg), ("longitude", lon_deg), ("height", height_m)):
        if not math.isfinite(v):
            raise InputFileError(f"ECEF origin {name} must be finite, got {v!r}")
    if abs(lat_deg) > 90:
        raise InputFileError(f"ECEF origin latitude must be in [-90, 90], got {lat_deg}")
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    east = [-math.sin(lon), math.cos(lon), 0.0]
    north = [-math.sin(lat) * math.cos(lon), -math.sin(lat) * math.sin(lon), math.cos(lat)]
    up = [math.cos(lat) * math.cos(lon), math.cos(lat) * math.sin(lon), math.sin(lat)]
    return np.array([east, north, up])


def rotate_pose(pose_ecef: Pose, R_enu_from_ecef: np.ndarray) -> Pose:
    """The same camera in the world rotated by ``R_enu_from_ecef`` (new = R @ old) about the world origin."""
    return Pose.from_rotation_center(
        R_enu_from_ecef @ pose_ecef.R_world_from_cam, pose_ecef.center @ R_enu_from_ecef.T
    )


def rotate_model(model: CityModel, R_enu_from_ecef: np.ndarray) -> CityModel:
    """``model`` with its world coordinates rotated by ``R_enu_from_ecef`` about the world origin,
    re-classified by its normals in the new frame (walls / roofs depend on which way is up)."""
    xyz_ecef = model.vertices.astype(np.float64) + model.origin
    stats = ParseStats(warnings=list(model.stats.warnings) + ["rotated from an ECEF-shifted frame into ENU"])
    builder = MeshBuilder(stats)
    for building_id in model.building_ids:
        builder.building(building_id)
    lods = np.unique(model.lods)
    for lod in lods:
        sel = model.lods == lod
        builder.add_mesh(
            xyz_ecef @ R_enu_from_ecef.T,
            model.triangles[sel],
            np.full(int(sel.sum()), UNLABELLED),
            model.building_index[sel],
            int(lod),
        )
    return builder.build(crs=None, source_crs=model.source_crs, source=model.source)


def vertical_share(model: CityModel, up: np.ndarray) -> float:
    """Share of the steep area (normal more than ``STEEP_MIN_DEG`` from ``up``) whose normal is within
    ``VERTICAL_TOLERANCE_DEG`` of horizontal: ~1 for the true up of a LoD model."""
    corners = model.vertices[model.triangles].astype(np.float64)
    n = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    area = 0.5 * np.linalg.norm(n, axis=1)
    ok = area > 0
    cos_up = np.abs(n[ok] @ (np.asarray(up, dtype=np.float64) / np.linalg.norm(up))) / (2 * area[ok])
    steep = cos_up < math.cos(math.radians(STEEP_MIN_DEG))
    vertical = cos_up < math.sin(math.radians(VERTICAL_TOLERANCE_DEG))
    total = float(area[ok][steep].sum())
    return float(area[ok][vertical].sum() / total) if total > 0 else 0.0


def detect_vertical(model: CityModel) -> tuple[bool, float]:
    """(is z up?, vertical share of the steep area for z) of a LoD model (module docstring)."""
    share = vertical_share(model, np.array([0.0, 0.0, 1.0]))
    return share >= MIN_VERTICAL_SHARE, share


# ---------------------------------------------------------------------------------------------- reading
def _is_scene(folder: Path) -> bool:
    return any((folder / d).exists() for d in (IMAGE_DIR, GT_DIR, GT_TEXT, PRIOR_DIR, PRIOR_TEXT))


def _base(name: str) -> str:
    return name.replace("\\", "/").split("/")[-1]


def _text_poses(path: Path) -> dict[str, Pose]:
    return {_base(k): v for k, v in read_poses(path).items()} if path.is_file() else {}


def _text_intrinsics(path: Path) -> dict[str, str]:
    """``{image name: its intrinsics line}`` of a scene ``intrinsic.txt`` (parsed per query)."""
    if not path.is_file():
        return {}
    out = {}
    for line in path.read_text(encoding="utf-8").splitlines():
        tokens = line.split()
        if tokens and not line.lstrip().startswith("#"):
            out[_base(tokens[0])] = line.strip()
    return out


def _image_size(path: Path | None) -> tuple[int | None, int | None]:
    if path is None:
        return None, None

    return image_size(path, "the query image")


def _names(scene_dir: Path, text_names: set[str]) -> tuple[list[str], dict[str, Path]]:
    images = {}
    img_dir = scene_dir / IMAGE_DIR
    if img_dir.is_dir():
        for p in sorted(img_dir.iterdir()):
            if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file():
                images[p.name] = p
    if images:
        return list(images), images
    names = {p.name[: -len("_pose.txt")] for p in (scene_dir / GT_DIR).glob("*_pose.txt")}
    names |= {p.name[: -len("_pose.txt")] for p in (scene_dir / PRIOR_DIR).glob("*_pose.txt")}
    return sorted(names | text_names), {}


def _pose_of(
    folder: Path, stem: str, text: dict[str, Pose], name: str, warnings: list[str], what: str
) -> tuple[Pose | None, Path | None]:
    """(the pose of query ``name`` from ``folder/<stem>_pose.txt`` or the scene's text file, that file)."""
    file = folder / f"{stem}_pose.txt"
    pose = read_pose(file) if file.is_file() else None
    other = text.get(name)
    if other is None:
        other = text.get(stem)
    if pose is not None and other is not None:
        gap = float(np.linalg.norm(pose.center - other.center))
        if gap > TEXT_FILE_TOLERANCE_M:
            warnings.append(f"{name}: {what} in {folder.name}/ and the scene text file differ by {gap:.3f} m")
    if pose is not None:
        return pose, file
    return other, (folder.parent / f"{folder.name}.txt" if other is not None else None)


def _camera_of(
    scene_dir: Path, name: str, stem: str, intr_text: dict[str, str], photo: tuple[str, int, int] | None
) -> Camera | str:
    """The camera of query ``name`` from ``intrinsic/<stem>_intrinsic.txt`` or the scene's text file, or why
    it has none: no intrinsics, or intrinsics of another image than its photo (``photo``: name and size
    when the scene has the image; ``geometry.io.check_fits_photo``), which would localize nothing."""
    k_file = scene_dir / INTRINSIC_DIR / f"{stem}_intrinsic.txt"
    if k_file.is_file():
        spec = k_file
    elif name in intr_text or stem in intr_text:
        spec = intr_text.get(name) or intr_text[stem]
    else:
        return f"no intrinsics ({INTRINSIC_DIR}/ or {INTRINSIC_TEXT})"
    width, height = (photo[1], photo[2]) if photo is not None else (None, None)
    try:
        return read_intrinsics(spec, width, height, photo=photo)
    except IntrinsicsMismatchError as exc:
        return str(exc)


def _read_scene(scene_dir: Path, warnings: list[str]) -> list[LodLocQuery]:
    gt_text = _text_poses(scene_dir / GT_TEXT)
    prior_text = _text_poses(scene_dir / PRIOR_TEXT)
    intr_text = _text_intrinsics(scene_dir / INTRINSIC_TEXT)
    names, images = _names(scene_dir, set(gt_text) | set(prior_text))
    if images:
        extra = sorted((set(gt_text) | set(prior_text)) - set(images))
        if extra:
            warnings.append(
                f"{scene_dir.name}: {len(extra)} pose(s) in the text files have no image in {IMAGE_DIR}/ "
                f"(ignored): {', '.join(extra[:3])}"
            )
    queries = []
    for name in names:
        stem = Path(name).stem if name in images else name
        image = images.get(name)
        width, height = _image_size(image)
        camera = _camera_of(scene_dir, name, stem, intr_text, (name, width, height) if image else None)
        if isinstance(camera, str):
            warnings.append(f"{scene_dir.name}/{name}: {camera}{SKIPPED}")
            continue
        points = scene_dir / POINTS_DIR / f"{stem}_points.npy"
        gt, gt_file = _pose_of(scene_dir / GT_DIR, stem, gt_text, name, warnings, "GT pose")
        prior, prior_file = _pose_of(scene_dir / PRIOR_DIR, stem, prior_text, name, warnings, "GPS prior")
        queries.append(
            LodLocQuery(
                name=name,
                scene=scene_dir.name,
                camera=camera,
                image_path=image,
                gt_pose_world=gt,
                prior_pose_world=prior,
                points_path=points if points.is_file() else None,
                gt_pose_file=gt_file,
                prior_pose_file=prior_file,
            )
        )
    return queries


def read_split(path: str | os.PathLike, stage: str | None = None) -> dict[str, set[str]]:
    """``{scene: {names}}`` of one stage of a LoD-Loc split JSON (default: ``val``, else the only stage)."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError as exc:
        raise InputFileError(f"{path}: no such split file") from exc
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputFileError(f"{path}: not a readable split JSON ({exc})") from exc
    if not isinstance(data, dict) or not data or not all(isinstance(v, dict) for v in data.values()):
        raise InputFileError(f"{path}: a split must be {{stage: {{scene: [names]}}}}")
    if stage is None:
        stage = "val" if "val" in data else next(iter(data)) if len(data) == 1 else None
        if stage is None:
            raise InputFileError(f"{path}: several stages ({', '.join(data)}); choose one")
    if stage not in data:
        raise InputFileError(f"{path}: no stage {stage!r} (have {', '.join(data)})")
    out = {}
    for scene, names in data[stage].items():
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            raise InputFileError(f"{path}: {stage}/{scene} must be a list of image names")
        out[scene] = {_base(n) for n in names}
    return out


def _find_model(root: Path, scene_dirs: list[Path]) -> Path | None:
    for folder in [root, *scene_dirs, root.parent]:
        objs = sorted(p for p in folder.glob("*.obj") if p.is_file())
        if len(objs) == 1:
            return objs[0]
        if len(objs) > 1:
            raise InputFileError(
                f"{folder}: several OBJ models ({', '.join(p.name for p in objs[:3])}); pass one "
                f"({parameter('city')})"
            )
    return None


def read_lodloc(
    root: str | os.PathLike,
    city: str | os.PathLike | None = None,
    split: str | os.PathLike | None = None,
    stage: str | None = None,
    frame: str = FRAME_AUTO,
    ecef_origin_llh: tuple[float, float, float] | None = None,
) -> LodLocDataset:
    """Read a LoD-Loc scene folder or a data set folder of scenes (module docstring).

    Args:
        root: a scene folder (has ``Query_image/`` or pose files) or a folder of scene folders.
        city: the LoD model (default: the one ``*.obj`` in the root, a scene folder or the root's parent).
        split: a split JSON; only its ``stage`` images are kept. A single-scene root whose folder name is
            not a scene of the split keeps the names of all its scenes (the demo's scene is ``demo``).
        frame: ``"auto"`` (test the model), ``"z-up"`` (use as is) or ``"ecef"`` (ECEF minus an origin:
            rotated into ENU at ``ecef_origin_llh``, default Swiss-EPFL's).
    """
    root = Path(root)
    if frame not in FRAMES:
        raise unknown_choice("frame", frame, FRAMES, InputFileError)
    if ecef_origin_llh is not None and frame != FRAME_ECEF:
        raise InputFileError("an ECEF origin is only used with frame='ecef'")
    if not root.is_dir():
        raise InputFileError(f"{root}: no such LoD-Loc data set folder")
    scene_dirs = (
        [root] if _is_scene(root) else sorted(d for d in root.iterdir() if d.is_dir() and _is_scene(d))
    )
    if not scene_dirs:
        raise InputFileError(
            f"{root}: not a LoD-Loc data set (no {IMAGE_DIR}/, {GT_DIR}/ or {GT_TEXT} here or one level down)"
        )
    warnings: list[str] = []
    queries: list[LodLocQuery] = []
    for scene_dir in scene_dirs:
        try:
            queries.extend(_read_scene(scene_dir, warnings))
        except SemCityLocError as exc:
            raise type(exc)(f"{scene_dir}: {exc}") from exc
    if split is not None:
        wanted = read_split(split, stage)
        single = len(scene_dirs) == 1 and scene_dirs[0].name not in wanted
        every = set().union(*wanted.values()) if wanted else set()
        queries = [q for q in queries if q.name in (every if single else wanted.get(q.scene, ()))]
    if not queries:  # why each image was skipped, else a user sees no reason at all
        skips = [w.removesuffix(SKIPPED) for w in warnings if w.endswith(SKIPPED)]
        why = f" ({'; '.join(skips[:3])}{'; ...' if len(skips) > 3 else ''})" if skips else ""
        raise InputFileError(
            f"{root}: no query images with intrinsics" + (" in the split" if split else "") + why
        )

    model_path = Path(city) if city is not None else _find_model(root, scene_dirs)
    if model_path is not None and not model_path.is_file():
        raise InputFileError(f"{model_path}: no such model file")
    dataset = LodLocDataset(root, queries, model_path, FRAME_Z_UP, "", None, warnings)
    _decide_frame(dataset, frame, ecef_origin_llh)
    return dataset


def _decide_frame(ds: LodLocDataset, frame: str, ecef_origin_llh) -> None:
    if frame == FRAME_ECEF:
        if ds.model_path is not None:
            is_up, share = detect_vertical(load_city_model(ds.model_path))
            if is_up:  # rotating a z-up model and its poses again tilts every wall and camera
                raise InputFileError(
                    f"{ds.model_path}: the model's walls are vertical in its own frame already ({share:.0%} "
                    "of the steep area within 3 deg of vertical): its z is up, it is no shifted ECEF; drop "
                    f"{parameter('frame', FRAME_ECEF)}"
                )
        llh = tuple(float(v) for v in (ecef_origin_llh or SWISS_EPFL_ECEF_ORIGIN_LLH))
        R_enu_from_ecef = enu_from_ecef(*llh)
        for q in ds.queries:
            q.gt_pose_world = (
                rotate_pose(q.gt_pose_world, R_enu_from_ecef) if q.gt_pose_world is not None else None
            )
            q.prior_pose_world = (
                rotate_pose(q.prior_pose_world, R_enu_from_ecef) if q.prior_pose_world is not None else None
            )
        ds.frame, ds.ecef_origin_llh = FRAME_ECEF, llh
        ds.frame_note = (
            f"ECEF minus an origin, rotated into ENU at lat {llh[0]}, lon {llh[1]}, h {llh[2]} (user said so)"
        )
        return
    if frame == FRAME_Z_UP:
        ds.frame_note = "z up (user said so)"
        return
    if ds.model_path is None:
        ds.frame_note = "z up assumed: no model to test the frame with"
        ds.warnings.append(ds.frame_note)
        return

    is_up, share = detect_vertical(load_city_model(ds.model_path))
    if not is_up:
        raise InputFileError(
            f"{ds.model_path}: the model's walls are not vertical in its frame (only {share:.0%} of the "
            "steep area is within 3 deg of vertical): z is not up. Swiss-EPFL's frame is ECEF minus an "
            f"origin: pass {parameter('frame', FRAME_ECEF)} and, for another data set, its ECEF origin "
            "(latitude, longitude, h)"
        )
    ds.frame_note = f"z up (detected: {share:.0%} of the model's steep area is vertical)"


# ---------------------------------------------------------------------------------------------- writing
def _write(path: Path, text: str) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(path, text)
    except OSError as exc:
        raise InputFileError(f"{path}: cannot write: {exc.strerror or exc}") from exc


def _matrix_text(M: np.ndarray) -> str:
    return "".join(" ".join(f"{v:.18e}" for v in row) + "\n" for row in M)


def write_lodloc_scene(
    scene_dir: str | os.PathLike, queries: list[LodLocQuery], text_files: bool = False
) -> Path:
    """Write the pose and intrinsics files of ``queries`` in LoD-Loc's layout (images are not copied).

    Per-image files always (``GT_pose/``, ``GPS_pose/``, ``intrinsic/``, numbers as LoD-Loc's
    ``np.savetxt`` writes them, ``%.18e``, which reads back exactly); with ``text_files`` also the scene
    text files ``GT_pose.txt`` / ``GPS_pose.txt`` (``name qw qx qy qz tx ty tz``) and ``intrinsic.txt``.
    """
    folder = Path(scene_dir)
    gt_lines, prior_lines, k_lines = [], [], []
    for q in queries:
        c = q.camera
        K = np.hstack([c.K, np.zeros((3, 1))])
        _write(folder / INTRINSIC_DIR / f"{q.stem}_intrinsic.txt", _matrix_text(K))
        k_lines.append(f"{q.name} PINHOLE {c.width} {c.height} {c.fx!r} {c.fy!r} {c.cx!r} {c.cy!r}")
        poses = ((q.gt_pose_world, GT_DIR, gt_lines), (q.prior_pose_world, PRIOR_DIR, prior_lines))
        for pose, sub, lines in poses:
            if pose is None:
                continue
            _write(folder / sub / f"{q.stem}_pose.txt", _matrix_text(pose.world_from_cam))
            qvec, tvec = colmap_qvec_tvec(pose)
            lines.append(" ".join([q.name, *(repr(float(v)) for v in [*qvec, *tvec])]))
    if text_files:
        for name, lines in ((GT_TEXT, gt_lines), (PRIOR_TEXT, prior_lines), (INTRINSIC_TEXT, k_lines)):
            if lines:
                _write(folder / name, "\n".join(lines) + "\n")
    return folder
