"""A folder of a user's photos and what belongs to each: intrinsics, a prior pose (and its uncertainty),
optionally a ground-truth pose.

Why: ``semcityloc label`` and ``semcityloc run`` take photos as users have them: a folder of images and
per-photo information in whatever form they come with. This module matches each photo to it by name
(exact file name, then stem):

- poses (``PoseFiles``): a COLMAP ``images.txt`` / ``images.bin`` or the model folder holding one (or
  any file ``geometry.io.read_poses`` reads) or a folder of LoD-Loc ``<stem>_pose.txt`` (4x4
  camera-to-world) or of a run's pose records (``semcityloc run``'s ``poses/<stem>.json``), in the
  model's CRS / frame;
- intrinsics (``IntrinsicsFiles``): ``exif`` (``dji_camera.dewarp_lens``: DJI's calibration with lens
  distortion, else ``dji_camera.camera_from_exif``: DJI's calibration tags, else the 35 mm-equivalent
  focal length of the photo's EXIF), one file for every photo (LoD-Loc ``*_intrinsic.txt``, COLMAP line,
  JSON, ``fx,fy,cx,cy[,w,h]``), a COLMAP ``cameras.txt`` / ``cameras.bin`` (camera ids from the poses')
  or a folder of ``<stem>_intrinsic.txt``. The photo's own size always wins (intrinsics of that image
  at another size are rescaled); intrinsics of another image (another aspect, a principal point more than
  ``PRINCIPAL_POINT_TOLERANCE`` off the photo's centre) raise ``IntrinsicsMismatchError``. A calibration
  with lens distortion (COLMAP ``OPENCV`` / ``RADIAL`` / ``SIMPLE_RADIAL``, JSON ``k1 k2 p1 p2 k3``) comes
  with it (``PhotoCamera``): the photo and its mask and depth are then
  resampled onto the pinhole camera (``geometry.distortion``);
- priors (``PriorFiles``): ``exif`` (the photo's DJI EXIF/XMP: ``dji.dji_prior`` into the model's CRS, its
  uncertainty from the RTK tags: ``dji.prior_uncertainty``), a geotag CSV (``datasets.geotags``: WGS 84
  + angles, converted the same way; accuracy columns = uncertainty) or a pose file / folder as above;
  a height that could not be converted widens the height sigma either way (``dji.height_widened``), and a
  photo whose tags have no heading (no ``GimbalYawDegree``, its pitch known; stop 53) or whose geotag row
  has no yaw (stop 54) gets yaw 0 and a yaw sigma that searches every heading, whatever ``--prior-sigma``
  says (``PhotoPrior.searched``); one without a pitch, its tags' or its row's (stop 55), has no prior.

A photo lacking something is not an error of the whole batch: ``PhotoMissing`` names what is missing and
the caller skips that photo with the reason.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyproj

from semcityloc.citymodel.crs import parse_crs_name
from semcityloc.citymodel.pose_crs import check_declared_frame, read_pose_world
from semcityloc.datasets.colmap import (
    ColmapCamera,
    ColmapImage,
    model_file,
    read_cameras_binary,
    read_images_binary,
)
from semcityloc.datasets.dji import (
    HEIGHT_AUTO,
    NO_HEADING_NOTE,
    NO_HEADING_TRUTH,
    dji_prior,
    height_widened,
    prior_uncertainty,
)
from semcityloc.datasets.dji_camera import calibrated_intrinsics, camera_from_exif, dewarp_lens
from semcityloc.datasets.dji_metadata import DjiMetadata, read_dji_metadata
from semcityloc.datasets.geotags import NO_YAW_NOTE, read_geotags_csv
from semcityloc.errors import (
    CameraError,
    CRSError,
    InputFileError,
    IntrinsicsMismatchError,
    SemCityLocError,
    parameter,
    shown_names,
)
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.distortion import LensDistortion
from semcityloc.geometry.intrinsics_files import check_fits_photo, read_lens
from semcityloc.geometry.pose import Pose
from semcityloc.geometry.pose_files import read_pose_text
from semcityloc.geometry.uncertainty import PriorUncertainty

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp")
EXIF = "exif"  # --priors / --intrinsics value: from the photo's own metadata


class PhotoMissing(InputFileError):
    """One photo lacks something (a prior, intrinsics, a mask); the batch goes on without it."""


class PhotoNotListed(PhotoMissing):
    """A pose file or folder, or a geotag CSV, that has nothing for the photo (no entry, row or file of its
    name), as opposed to one whose entry cannot be used: ground truth is optional per photo, a broken
    entry of it is not (``benchmark.photo_inputs``)."""


def photo_metadata(image: Path) -> DjiMetadata:
    """``dji_metadata.read_dji_metadata`` of a photo; ``PhotoMissing`` with its message when it cannot be
    read (a malformed tag, say): that photo is skipped, not the run."""
    try:
        return read_dji_metadata(image)
    except SemCityLocError as exc:
        raise PhotoMissing(str(exc)) from None


def check_images_folder(folder: str | os.PathLike) -> Path:
    """``folder`` when it is a folder; else ``InputFileError`` saying what it is: a file (one photo given
    where its folder is wanted: ``semcityloc localize`` takes one image) or nothing at all."""
    folder = Path(folder)
    if folder.is_dir():
        return folder
    if folder.exists():
        raise InputFileError(
            f"{folder}: is a file, not a folder of photos: give its folder "
            f"({parameter('localize_one')} takes one image)"
        )
    raise InputFileError(f"{folder}: no such images folder")


def list_images(
    folder: str | os.PathLike,
    every_entry: bool = False,
    recursive: bool = False,
    skip_dir: Callable[[Path], bool] | None = None,
    remedy: str = "give that subfolder as the images folder",
) -> list[Path]:
    """The image files of a folder (``IMAGE_SUFFIXES``, ``check_images_folder``), sorted by name; with
    ``every_entry``, also what is named like one but is not a file (a folder ``x.jpg``, a broken link), for
    the caller to report.

    Only the folder's top level unless ``recursive`` (a DJI card: ``DCIM/100MEDIA/``), which also reads its
    subfolders (``subfolder_images``: not hidden ones, nor those ``skip_dir`` names) and refuses two photos
    of one stem (outputs are named by it: ``a/DJI_0001.JPG`` and ``b/DJI_0001.JPG`` would overwrite each
    other's). A folder without images at its top level but with some in its subfolders says so, with
    ``remedy``."""
    folder = check_images_folder(folder)
    images = sorted(
        p for p in folder.iterdir() if (every_entry or p.is_file()) and p.suffix.lower() in IMAGE_SUFFIXES
    )
    if recursive:
        images = sorted(images + subfolder_images(folder, skip_dir), key=lambda p: p.relative_to(folder))
        check_unique_stems(folder, images)
    if not images:
        nested = subfolder_images(folder, skip_dir)
        where = ""
        if nested:
            shown = shown_names([str(p.relative_to(folder)) for p in nested])
            verb = "is" if len(nested) == 1 else "are"
            where = f" at its top level; {len(nested)} in its subfolders ({shown}) {verb} not read: {remedy}"
        raise InputFileError(f"{folder}: no images ({', '.join(IMAGE_SUFFIXES)}){where}")
    return images


def subfolder_images(folder: Path, skip_dir: Callable[[Path], bool] | None = None) -> list[Path]:
    """The image files in the subfolders of ``folder`` at any depth (not its top level), sorted by their
    path; hidden folders (``.thumbnails``) and those ``skip_dir`` names are not entered."""
    found = []
    for root, dirs, files in os.walk(folder):
        here = Path(root)
        dirs[:] = sorted(d for d in dirs if not d.startswith(".") and not (skip_dir and skip_dir(here / d)))
        if here != folder:
            found += [here / f for f in files if Path(f).suffix.lower() in IMAGE_SUFFIXES]
    return sorted(found, key=lambda p: p.relative_to(folder))


def check_unique_stems(folder: Path, images: list[Path]) -> None:
    """``InputFileError`` naming two photos of ``folder`` (read with its subfolders) that share a stem."""
    seen: dict[str, Path] = {}
    for image in images:
        if image.stem in seen:
            a, b = (str(p.relative_to(folder)) for p in (seen[image.stem], image))
            raise InputFileError(
                f"{folder}: {a} and {b} share the name {image.stem}, and every output of a photo is named by "
                "it: rename one, or run each subfolder on its own (with its own output folder)"
            )
        seen[image.stem] = image


def match_name(entries: dict, image: Path):
    """Entry for ``image`` in a name-keyed dict: exact file name, then stem (paths in keys allowed)."""
    for key in (lambda n: Path(n).name, lambda n: Path(n).stem):
        hits = [k for k in entries if key(k) == key(image.name)]
        if len(hits) == 1:
            return entries[hits[0]]
    return None


def per_stem_file(folder: Path, stem: str, suffix: str) -> Path | None:
    """``<stem>_<suffix>.txt`` or ``<stem>.txt`` in ``folder`` (LoD-Loc's per-image files)."""
    for name in (f"{stem}_{suffix}.txt", f"{stem}.txt"):
        if (folder / name).is_file():
            return folder / name
    return None


def colmap_file(path: Path, kind: str) -> Path | None:
    """The COLMAP ``<kind>.bin`` / ``<kind>.txt`` that ``path`` names: the file itself (``images.bin``, or
    any ``*.bin``: COLMAP text is read by ``geometry.io``), or the one in a model folder (``sparse/0``,
    refused when it holds both formats, ``colmap.model_file``); None for anything else (a LoD-Loc folder, a
    pose file)."""
    if path.is_dir():
        return model_file(path, kind)  # both formats there: refused, naming both
    return path if path.suffix.lower() == ".bin" else None


class PoseFiles:
    """Poses by image from a COLMAP model (``images.txt`` / ``images.bin`` or their folder), any file
    ``read_poses`` reads, or a LoD-Loc pose folder."""

    def __init__(
        self, spec: str | os.PathLike, crs: pyproj.CRS | None = None, crs_offset: np.ndarray | None = None
    ):
        """``crs``: the model's; ``crs_offset``: the model's frame is ``crs`` minus this (``run --offset``).
        A JSON pose file that declares another frame is refused (``CRSError``,
        ``citymodel.pose_crs.check_pose_crs``), the whole batch for one file, the photo for a folder's."""
        self.path = Path(spec)
        self.crs, self.crs_offset = crs, crs_offset
        if not self.path.exists():
            raise InputFileError(f"{self.path}: no such pose file or folder")
        colmap = colmap_file(self.path, "images")
        self.source = colmap or self.path  # the file the poses are read from (or the LoD-Loc folder)
        self.folder = self.path if colmap is None and self.path.is_dir() else None
        self.entries: dict[str, Pose] = {}
        self.binary_images: dict[str, ColmapImage] = {}
        self.camera_ids: dict[str, str] = {}
        if colmap is not None and colmap.suffix.lower() == ".bin":
            images = read_images_binary(colmap).values()
            self.binary_images = {image.name: image for image in images}  # posed when asked
            self.camera_ids = {image.name: str(image.camera_id) for image in images}
        elif self.folder is None:
            text = read_pose_text(self.source)  # read once: its frame, poses and camera ids
            check_declared_frame(text.frame, self.source, crs, "pose", crs_offset)
            self.entries = text.poses()
            self.camera_ids = text.camera_ids()

    def pose(self, image: Path) -> Pose | None:
        """The pose of ``image``, None when the source has none for it; in a folder a LoD-Loc
        ``<stem>_pose.txt`` / ``<stem>.txt`` or a run's ``poses/<stem>.json`` (``semcityloc run``'s record:
        ``PhotoNotListed`` saying so when that run did not localize the photo)."""
        if self.folder is not None:
            f = per_stem_file(self.folder, image.stem, "pose") or _pose_record(self.folder, image)
            if f is None:
                return None
            try:
                return read_pose_world(f, self.crs, crs_offset=self.crs_offset)
            except CRSError as exc:
                raise PhotoMissing(f"{f}: {exc}") from None
        if self.binary_images:
            entry = match_name(self.binary_images, image)
            if entry is None:
                return None
            try:
                return entry.pose
            except SemCityLocError as exc:
                raise PhotoMissing(f"{self.source}: image {entry.name!r}: {exc}") from None
        if list(self.entries) == [""]:
            return self.entries[""]
        return match_name(self.entries, image)

    def file_of(self, image: Path) -> Path:
        """The file the pose of ``image`` is read from (its folder's ``<stem>_pose.txt`` / ``<stem>.txt`` /
        ``<stem>.json``, else the one poses file), for messages about that pose."""
        if self.folder is not None:
            found = per_stem_file(self.folder, image.stem, "pose")
            return found or self.folder / f"{image.stem}.json"
        return self.source


def _pose_record(folder: Path, image: Path) -> Path | None:
    """``folder/<stem>.json`` of ``image``: a pose record as ``semcityloc run`` writes it into its
    ``poses/`` (``geometry.io.pose_to_dict``'s layout), None without one; ``PhotoNotListed`` when it is
    the record of a photo that run did not localize (its status and reason, no pose)."""
    path = folder / f"{image.stem}.json"
    if not path.is_file():
        return None
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return path  # read_pose says what is wrong with it
    if isinstance(record, dict) and "status" in record and "world_from_cam" not in record:
        why = record.get("reason") or record["status"]
        raise PhotoNotListed(f"{path}: {image.name} has no pose there: that run did not localize it ({why})")
    return path


def pose_folder_names(stem: str) -> str:
    """The files a pose folder (``PoseFiles``) may hold for the photo of ``stem``, for messages."""
    return f"{stem}_pose.txt, {stem}.txt or {stem}.json"


# Where a photo's camera came from with ``--intrinsics exif`` (``IntrinsicsFiles.photo_camera``).
INTRINSICS_DJI_CALIBRATION = "exif: DJI calibration (XMP CalibratedFocalLength)"
INTRINSICS_DJI_DEWARP = "exif: DJI calibration with lens distortion (XMP DewarpData)"
INTRINSICS_35MM = "exif: 35 mm-equivalent focal length (approximate)"
# What a user hears when a camera is ``INTRINSICS_35MM`` (``semcityloc localize``, once per photo run).
APPROXIMATE_INTRINSICS_NOTE = (
    "the camera is the EXIF's 35 mm-equivalent focal length (no calibration tags), which can be a few % off "
    "(2.4 % short on the real H20T thermal image) and moves the camera up or down by as much; pass a "
    f"calibration ({parameter('intrinsics', 'FILE')}; docs/your-data.md, section 4)"
)


@dataclass(frozen=True)
class PhotoCamera:
    """A photo's pinhole intrinsics, its lens distortion (zero: the photo is pinhole already) and where
    they came from (``IntrinsicsFiles.photo_camera``). Masks, depth and overlays of the photo are resampled
    onto ``camera`` with ``geometry.distortion.undistort_image``."""

    camera: Camera
    distortion: LensDistortion
    source: str


class IntrinsicsFiles:
    """Camera per image (module docstring); ``spec`` None: the file or folder beside ``poses``."""

    def __init__(self, spec: str | os.PathLike | None, poses: PoseFiles | None = None):
        self.poses = poses
        if spec is None:
            spec = self._default(poses)
        self.exif = str(spec) == EXIF
        self.path = Path(spec)
        if not self.exif and not self.path.exists():
            raise InputFileError(f"{self.path}: no such intrinsics file or folder")
        colmap = None if self.exif else colmap_file(self.path, "cameras")
        self.path = colmap or self.path
        self.folder = self.path if not self.exif and self.path.is_dir() else None
        self.binary: dict[str, ColmapCamera] | None = None  # a COLMAP cameras.bin's cameras by id
        if colmap is not None and colmap.suffix.lower() == ".bin":
            self.binary = {str(k): c for k, c in read_cameras_binary(colmap).items()}

    @staticmethod
    def _default(poses: PoseFiles | None) -> str:
        if poses is not None and poses.folder is not None:
            sibling = poses.folder.parent / "intrinsic"
            if sibling.is_dir():
                return str(sibling)
        elif poses is not None:  # the cameras file of the images file's format first, then the other
            suffixes = dict.fromkeys([poses.source.suffix.lower(), ".bin", ".txt"])
            for suffix in suffixes:
                if (poses.source.parent / f"cameras{suffix}").is_file():
                    return str(poses.source.parent / f"cameras{suffix}")
        raise InputFileError(
            f"no intrinsics given ({parameter('intrinsics')}) and none found beside the poses (expected "
            "cameras.txt or cameras.bin "
            "beside images.txt / images.bin, or an intrinsic/ folder beside the pose folder)"
        )

    def file_of(self, image: Path) -> Path | None:
        """The file the camera of ``image`` is read from: a folder's ``<stem>_intrinsic.txt`` (named as
        expected when it is missing), else the one file or COLMAP cameras file; None for ``exif`` (the
        photo's own metadata). What a photo run fingerprints (``benchmark.photo_inputs``)."""
        if self.exif:
            return None
        if self.folder is not None:
            found = per_stem_file(self.folder, image.stem, "intrinsic")
            return found or self.folder / f"{image.stem}_intrinsic.txt"
        return self.path

    def photo_camera(
        self, image: Path, width: int, height: int, meta: DjiMetadata | None = None
    ) -> PhotoCamera:
        """The camera of ``image`` at ``width`` x ``height``, its lens distortion and where they came from:
        ``INTRINSICS_DJI_DEWARP``, ``INTRINSICS_DJI_CALIBRATION``, ``INTRINSICS_35MM`` (approximate) or the
        calibration file. ``meta``: the photo's ``photo_metadata`` when the caller has read it already."""
        if self.exif:
            meta = meta if meta is not None else photo_metadata(image)
            lens = dewarp_lens(meta)
            if lens is not None:
                (camera, distortion), source = lens, INTRINSICS_DJI_DEWARP
            else:
                try:
                    camera, distortion = camera_from_exif(meta), LensDistortion()
                except CameraError as exc:
                    raise PhotoMissing(
                        f"{exc}: pass {parameter('intrinsics')} (a calibration file or folder)"
                    ) from None
                calibrated = calibrated_intrinsics(meta) is not None
                source = INTRINSICS_DJI_CALIBRATION if calibrated else INTRINSICS_35MM
            camera = camera if camera.size == (width, height) else camera.scaled(width, height)
            return PhotoCamera(camera, distortion, source)
        camera, distortion = self._from_files(image, width, height)
        return PhotoCamera(camera, distortion, str(self.path))

    def _from_files(self, image: Path, width: int, height: int) -> tuple[Camera, LensDistortion]:
        """The camera of ``image`` from the calibration file or folder, checked to fit the photo
        (``geometry.io.check_fits_photo``: ``IntrinsicsMismatchError`` naming file, photo and sizes)."""
        photo = (image.name, width, height)
        if self.binary is not None:
            return self._from_binary(self.binary, image, photo)
        if self.folder is not None:
            f = per_stem_file(self.folder, image.stem, "intrinsic")
            if f is None:
                raise PhotoMissing(f"{self.folder}: no {image.stem}_intrinsic.txt for {image.name}")
            return read_lens(f, width=width, height=height, photo=photo)
        try:  # one camera for every photo
            return read_lens(self.path, width=width, height=height, photo=photo)
        except IntrinsicsMismatchError:
            raise
        except CameraError:
            pass
        # Several cameras: COLMAP cameras.txt is keyed by camera id (from images.txt), other files by name.
        camera_id = None
        if self.poses is not None and self.poses.camera_ids:
            camera_id = match_name(self.poses.camera_ids, image)
        try:
            return read_lens(self.path, width=width, height=height, name=camera_id or image.name, photo=photo)
        except IntrinsicsMismatchError:
            raise
        except CameraError as exc:
            raise PhotoMissing(f"{self.path}: no intrinsics for {image.name} ({exc})") from None

    def _from_binary(
        self, cameras: dict[str, ColmapCamera], image: Path, photo: tuple[str, int, int]
    ) -> tuple[Camera, LensDistortion]:
        """The camera of ``image`` among a COLMAP ``cameras.bin``'s ``cameras`` (its id from the poses'
        ``images``; the only camera when the poses name none), checked to fit the photo, at its size."""
        camera_id = None
        if self.poses is not None and self.poses.camera_ids:
            camera_id = match_name(self.poses.camera_ids, image)
        if camera_id is None and len(cameras) == 1:
            camera_id = next(iter(cameras))
        if camera_id not in cameras:
            raise PhotoMissing(f"{self.path}: no camera for {image.name} (camera ids {sorted(cameras)})")
        try:
            camera, lens = cameras[camera_id].to_lens_camera()
        except CameraError as exc:
            raise PhotoMissing(f"{self.path}: {exc}") from None
        check_fits_photo(camera, str(self.path), photo)
        _, width, height = photo
        return camera.scaled(width, height), lens  # at the photo's size (the same camera when it is)


@dataclass
class PhotoPrior:
    """A photo's prior pose in the model's frame (its CRS minus ``offset``), how far it may be off and
    where it came from (``details``: JSON-ready, e.g. how the height was treated)."""

    pose_world: Pose
    uncertainty: PriorUncertainty | None  # None: the caller's default
    source: str
    details: dict = field(default_factory=dict)
    heading_known: bool = True  # False: the tags or the geotag row had no heading, yaw taken as 0
    no_heading_note: str = NO_HEADING_NOTE  # said of it without a heading (a geotag row's: ``NO_YAW_NOTE``)
    no_heading_truth: str = NO_HEADING_TRUTH  # why it is then no true pose (``benchmark.photo_inputs``)

    def searched(self, stated: PriorUncertainty | None = None) -> PriorUncertainty:
        """The uncertainty the localizer searches for this prior: ``stated`` (``--prior-sigma``, the same
        for every photo) when given, else its own, else the defaults; with every heading when the prior
        has none (``PriorUncertainty.without_heading``: a yaw sigma stated for photos with a heading
        would search around an arbitrary one)."""
        sigma = stated or self.uncertainty or PriorUncertainty()
        return sigma if self.heading_known else sigma.without_heading()

    def warnings(self) -> list[str]:
        """What a result of this prior says about it: that every heading was searched, when it had none."""
        return [] if self.heading_known else [self.no_heading_note]


class PriorFiles:
    """Priors by image (module docstring): ``exif``, a geotag ``.csv`` or a pose file / folder.

    ``crs``: the model's CRS (needed for ``exif`` and CSV priors, which are WGS 84); ``offset``: the
    model's frame is that CRS minus ``offset``; ``target_height`` / ``geoid_separation_m``: as in
    ``dji.dji_prior``.
    """

    def __init__(
        self,
        spec: str | os.PathLike,
        crs: pyproj.CRS | str | None,
        offset: np.ndarray | None = None,
        target_height: str = HEIGHT_AUTO,
        geoid_separation_m: float | None = None,
    ):
        self.spec = str(spec)
        self.exif = self.spec == EXIF  # from each photo's own metadata
        self.crs, self.offset = crs, offset
        self.target_height, self.geoid_separation_m = target_height, geoid_separation_m
        self.geotags = None
        self.files = None
        path = Path(self.spec)
        if self.spec != EXIF and path.suffix.lower() == ".csv":
            self.geotags = read_geotags_csv(path)
        elif self.spec != EXIF:
            self.files = PoseFiles(path, parse_crs_name(crs) if isinstance(crs, str) else crs, offset)
        if self.files is None and crs is None:
            what = "the photos' DJI GPS priors" if self.spec == EXIF else f"WGS 84 priors ({path.name})"
            raise CRSError(
                f"{what} need the city model's CRS, and the model names none: pass it "
                f"({parameter('crs', 'EPSG:25832')}, say), or priors already in the model's frame "
                f"({parameter('priors', 'GPS_pose/')} or a COLMAP images.txt)"
            )

    def _from_dji(
        self,
        meta,
        source: str,
        source_height: str,
        stated: PriorUncertainty | None = None,
        where: str = "",
        geotag: bool = False,
    ) -> PhotoPrior:
        """The prior of ``meta`` (a photo's DJI metadata, a geotag row's: ``where`` names the row) with its
        uncertainty: ``stated`` (a geotag row's accuracies, else the defaults) or, for a photo's own metadata
        (``stated`` None and ``source`` exif), its RTK tags; either way widened when its height was not
        converted (``dji.height_widened``, one rule for every source; no heading: ``PhotoPrior.searched``).
        ``PhotoMissing`` when it gives no prior in the model's CRS (no GNSS fix, a position outside the CRS's
        area of use, its latitude and longitude swapped, no gimbal pitch: ``dji.dji_prior``): that photo
        skipped, not the run. ``geotag``: ``meta`` is a geotag row's (without a yaw it says so in its words:
        ``geotags.NO_YAW_NOTE``)."""
        no_heading = NO_YAW_NOTE if geotag else NO_HEADING_NOTE
        try:
            prior = dji_prior(
                meta,
                self.crs,
                offset=self.offset,
                source_height=source_height,
                target_height=self.target_height,
                geoid_separation_m=self.geoid_separation_m,
                no_heading_note=no_heading,
            )
        except (InputFileError, CRSError) as exc:
            raise PhotoMissing(f"no usable GPS prior{f' ({where})' if where else ''}: {exc}") from None
        details = prior.as_dict()
        if source == EXIF:
            sigma = prior_uncertainty(prior)
        elif stated is None and not prior.height_unconverted:
            sigma = None  # the caller's default
        else:
            sigma = height_widened(stated or PriorUncertainty(), prior)
        untrue = f"its geotag row ({where}) has no yaw (heading)" if geotag else NO_HEADING_TRUTH
        return PhotoPrior(prior.pose, sigma, source, details, prior.heading_known, no_heading, untrue)

    def prior(self, image: Path, meta: DjiMetadata | None = None) -> PhotoPrior:
        """The prior of ``image``; ``PhotoNotListed`` when the files have none for it, ``PhotoMissing`` when
        the one they have cannot be used (``SemCityLocError`` for a CRS that cannot hold it). ``meta``: the
        photo's ``photo_metadata`` when the caller has read it already (used by ``exif`` priors only)."""
        if self.files is not None:
            pose = self.files.pose(image)
            if pose is None:
                expected = (
                    f" (expected {pose_folder_names(image.stem)})" if self.files.folder is not None else ""
                )
                raise PhotoNotListed(f"no prior pose for {image.name} in {self.files.path}{expected}")
            return PhotoPrior(pose, None, f"pose file {self.files.path.name}")
        if self.geotags is not None:
            row = match_name(self.geotags, image)
            if row is None:
                raise PhotoNotListed(f"no row for {image.name} in {self.spec}")
            source = f"geotags {Path(self.spec).name}"
            where = f"{self.spec} line {row.line}" if row.line is not None else str(self.spec)
            if row.geotag is None:  # no pitch: skipped, as a DJI photo without GimbalPitchDegree
                raise PhotoMissing(f"no usable GPS prior ({where}): {row.unusable}")
            return self._from_dji(
                row.geotag.metadata(), source, row.source_height(), row.uncertainty(), where, geotag=True
            )
        return self._from_dji(meta if meta is not None else photo_metadata(image), EXIF, HEIGHT_AUTO)
