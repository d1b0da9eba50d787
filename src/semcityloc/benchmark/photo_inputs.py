"""A photo run's inputs, found and checked for every photo before anything is localized (``resolve_inputs``).

Why before the run: what a run can use is settled before its first photo, so that a photo lacking an input
is named with the reason instead of stopping the run at its turn, and the run's identity (``run.json``'s
``query_names`` and ``skipped_photos``) is known when the run starts.

Per photo (``datasets.photos`` matches files to photos by name):

- intrinsics: ``exif`` (DJI's calibration with its lens distortion, ``dji_camera.dewarp_lens``, else
  DJI's calibration tags, else the 35 mm-equivalent focal length, ``dji_camera.camera_from_exif``) by
  default, or a calibration (LoD-Loc ``intrinsic/`` folder, COLMAP ``cameras.txt``, one file for all),
  which must fit the photo (``geometry.io.check_fits_photo``: its size or resized, a principal point near
  the centre; else treated as a mask of another aspect is, ``_photo_camera``); with lens distortion, the
  photo, its mask and its depth are resampled onto the pinhole camera before anything uses them
  (``PhotoInput.pinhole``); a camera whose focal length is the approximate 35 mm one gets the one its
  flight's oblique photos prefer afterwards (``benchmark.photo_focal``);
- prior: the photo's DJI EXIF/XMP by default (``dji.dji_prior`` into the model's CRS), or a geotag CSV, a
  COLMAP ``images.txt`` or a LoD-Loc ``GPS_pose/`` folder (in the model's frame);
- how far the prior may be off (``PriorUncertainty``): ``prior_sigma`` when given (the same for every
  photo), else the photo's RTK tags (``dji.prior_uncertainty``) or the geotag file's accuracy columns,
  else the defaults; every heading for a prior without one (``PhotoPrior.searched``: a DJI photo without
  ``GimbalYawDegree``, a geotag row without a yaw). Kept in each query
  (``BenchmarkQuery.prior_uncertainty``) and in the outputs;
- perception: precomputed masks (``<masks>/<stem>.png|.npy``, or ``.jpg|.jpeg`` with ``allow_lossy_mask``;
  also named ``<photo name>.png``, e.g. ``P0.JPG.png``; any resolution with the photo's aspect),
  or a segmentation backend run on the photo (shrunk to ``PHOTO_MAX_WIDTH``); optional depth likewise;
- optional ground truth (``truth``, same forms as the priors): rows then carry errors and the summary
  recall. A photo the truth does not list runs without; one whose entry cannot be used (a file that does
  not read, of another CRS) is skipped with the reason (``_true_pose``), not run without a word.

The photos are those of the folder's top level (with ``recursive`` its subfolders' too: ``photo_paths``).
A photo that lacks any of these (a prior without a GNSS fix, or outside the CRS's area of use, is none:
``PriorFiles``), or whose file cannot be read (not a file, empty, truncated, corrupt, a
format Pillow does not read: its pixels are decoded once here, ``_readable_photo``), or whose mask's header
says it cannot be used (a lossy format without ``allow_lossy_mask``, not class ids: ``_mask_file``), or whose
prior lies so far from every building that no view of its search could see one (``_on_the_map``), is
skipped before anything is localized, with the reason naming the file (``run.json`` ``skipped_photos``, the
summary, the CLI's closing lines); the others run. With ground truth (``truth``), a photo that has a true
pose and whose own input (the photo, its mask or depth) is missing, cannot be read (not a file, empty,
corrupt, truncated, no class ids) or does not fit the photo (another aspect; intrinsics of another image)
is not skipped but a miss of the run, found here or, for a file that fails only when read in full, at its
turn (``benchmark.photo_source``): a ``not_localized`` row with the reason naming the file
(``results.unreadable_result``, ``PhotoInput.unreadable``), in every recall's denominator, as in a data-set
benchmark, so that recall is never over the photos that happened to have usable inputs. So is, since stop
53, a photo with a true pose skipped for any other cause (no usable prior or intrinsics, a prior off the
map, a mask in a lossy format without ``allow_lossy_mask``): a ``not_localized`` row whose reason is
``skipped, counted as a miss: `` and the skip's (``results.skipped_miss_result``, ``PhotoInput.skipped``).
A photo without a true pose is skipped, and so is one whose true pose cannot be used
(``TruthUnusable``). With a tile store for the city, the map
of the run's overlays and exports is the store's tiles within a camera's range of the priors
(``flight_area``).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from semcityloc.benchmark.runfiles import RUN_FILE
from semcityloc.benchmark.spec import resolve_city
from semcityloc.citymodel.model import CityModel
from semcityloc.citymodel.tiles import TileStore
from semcityloc.datasets.geodesy import check_model_in_crs
from semcityloc.datasets.photos import (
    EXIF,
    IMAGE_SUFFIXES,
    IntrinsicsFiles,
    PhotoCamera,
    PhotoMissing,
    PhotoNotListed,
    PhotoPrior,
    PriorFiles,
    check_unique_stems,
    list_images,
    photo_metadata,
    subfolder_images,
)
from semcityloc.errors import InputFileError, IntrinsicsMismatchError, LossyMaskError, parameter
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.distortion import LensDistortion, undistort_image
from semcityloc.geometry.pose import Pose
from semcityloc.geometry.uncertainty import PriorUncertainty
from semcityloc.io.images import (
    check_aspect_of_photo,
    check_label_header,
    decoded_size_and_orientation,
    image_size,
    label_maps_beside_photos,
)
from semcityloc.io.stamps import file_fingerprint, paths_stamp
from semcityloc.localization.search_reach import MAX_VIEW_RANGE_M, MapLayout
from semcityloc.perception.files import DEPTH_SUFFIXES, find_file, find_mask, mask_suffixes, named_file

if TYPE_CHECKING:
    # for annotations only: ``photo_spec`` imports this module, so importing it back would be a cycle
    from semcityloc.benchmark.photo_spec import PhotoSpec


# The key of ``PhotoInput.fingerprints`` in a query's meta (so in its row's ``meta_json``) and its record.
INPUT_FINGERPRINTS = "input_fingerprints"


@dataclass
class PhotoInput:
    """One photo's resolved inputs (module docstring); poses in the model's world frame."""

    name: str
    path: Path
    camera: Camera | None  # None: an unreadable photo (``unreadable``) whose camera is in its own file
    prior: PhotoPrior | None  # likewise
    uncertainty: PriorUncertainty
    truth_world: Pose | None = None
    mask: Path | None = None
    depth: Path | None = None
    intrinsics_source: str = ""  # ``PhotoCamera.source``
    distortion: LensDistortion = LensDistortion()  # the photo's lens; zero: pinhole already
    # The flight's focal-length estimate for this camera (``photo_focal``; one dict per camera).
    focal_estimate: dict | None = None
    orientation: int = 1  # the photo's EXIF orientation (``io.images.exif_orientation``; 1: as stored)
    # Why a photo with a true pose cannot run: its own file cannot be read or used (checked before the
    # run). Its query is a miss naming the file, not skipped (module docstring); None: it runs.
    unreadable: str | None = None
    # Why a photo with a true pose was skipped for another cause (no usable prior or intrinsics, a prior off
    # the map, a lossy mask without ``allow_lossy_mask``): its query is a miss keeping that reason
    # (``results.skipped_miss_result``); None: it runs.
    skipped: str | None = None
    # The other files the photo's row is made from, fingerprinted since stop 53 (``fingerprints``): its
    # intrinsics file, a ``files`` backend's mask and depth; a path that is no file: fingerprint None.
    later_files: tuple[tuple[str, Path], ...] = ()

    @property
    def runs(self) -> bool:
        """Whether the photo is localized (not a miss decided before the run: ``unreadable``, ``skipped``)."""
        return self.unreadable is None and self.skipped is None

    @property
    def stem(self) -> str:
        return self.path.stem

    def fingerprints(self) -> dict[str, dict | None]:
        """``{"photo": fingerprint, "mask": ..., "depth": ..., "intrinsics": ...}`` of the files the photo's
        row is made from: its own (those it has) and ``later_files`` (always, None where there is no file)
        (``io.stamps.file_fingerprint``: name, size and SHA-256, None for one that is no file that reads):
        kept in the row (``meta_json``) and compared when the run finishes
        (``photo_exports.changed_inputs``)."""
        files = {"photo": self.path, "mask": self.mask, "depth": self.depth}
        own = {kind: file_fingerprint(path) for kind, path in files.items() if path is not None}
        return {**own, **{kind: file_fingerprint(path) for kind, path in self.later_files}}

    def later_kinds(self) -> set[str]:
        """The kinds of ``later_files``: a row of an earlier version (stop 52) holds none of them, and is not
        compared for them (``photo_exports.changed_files``)."""
        return {kind for kind, _ in self.later_files}

    def pinhole(self, image: np.ndarray, fill: float, nearest: bool) -> np.ndarray:
        """An array in the photo's geometry (the photo, a mask, a depth map; any resolution) resampled
        onto the pinhole ``camera`` (``geometry.distortion.undistort_image``)."""
        return undistort_image(image, self.camera, self.distortion, fill=fill, nearest=nearest)


class Resolved(NamedTuple):
    """What a ``PhotoSpec`` resolves to (``PhotoSpec.resolved``)."""

    model: CityModel  # the city file, or the tiles of a store within a camera's range of the flight
    inputs: list[PhotoInput]  # the photos that can run
    skipped: dict[str, str]  # {name: why not} of the others
    store: TileStore | None  # the ``--city`` tile store, opened once: the localizer's parts per photo


def inputs_stamp(spec: PhotoSpec) -> tuple:
    """The stamp of every file and folder ``spec`` names (``io.stamps.paths_stamp``: the photos, masks,
    depth, priors, truth and intrinsics, the city file or store, a backend option that is a path), taken
    before they are read: the key of the resolved inputs' cache in a process
    (``photo_focal.calibrated_inputs``), so that a file changed between two runs is read again."""
    named = [spec.images, spec.masks, spec.depth, spec.truth, *(v for _, v in spec.backend_options)]
    named += [p for p in (spec.priors, spec.intrinsics) if p != EXIF]
    return paths_stamp([*named, resolve_city(spec.city)])


def resolve_inputs(spec: PhotoSpec) -> Resolved:
    """``spec``'s model and every photo of its folder found and checked (module docstring): the photos that
    run (with a miss of the truth among them, ``PhotoInput.unreadable``), ``{name: why not}`` of the others,
    and the tile store (None for a file); the focal lengths as the intrinsics state them (``photo_focal``).
    Read anew at each call (``photo_focal.calibrated_inputs`` keeps it while the files are unchanged)."""
    model, store = spec.load_model()
    offset = None if spec.offset is None else np.asarray(spec.offset, dtype=np.float64)
    priors = PriorFiles(spec.priors, model.crs, offset, spec.target_height, spec.geoid_separation_m)
    truth = None
    if spec.truth:
        truth = PriorFiles(spec.truth, model.crs, offset, spec.target_height, spec.geoid_separation_m)
    intrinsics = IntrinsicsFiles(spec.intrinsics, priors.files)
    fixed = spec.fixed_uncertainty()
    inputs: list[PhotoInput] = []
    skipped: dict[str, str] = {}
    for path in photo_paths(spec):
        lens = prior = meta = None
        try:
            width, height, orientation = _readable_photo(path)
            # Read once when both the camera and the prior come from it (each would read the whole file).
            meta = photo_metadata(path) if intrinsics.exif and priors.exif else None
            lens = _photo_camera(intrinsics, path, width, height, meta)
            camera = lens.camera
            prior = priors.prior(path, meta)
            mask = _mask_file(spec, path, camera, orientation)
            depth = _input_file(spec.depth, path, _find_depth, "depth", camera, orientation)
            true_pose = _true_pose(truth, path, meta)
        except PhotoMissing as exc:
            reason, true_pose = str(exc), None
            if not isinstance(exc, TruthUnusable):
                try:
                    true_pose = _true_pose(truth, path, meta)
                except PhotoMissing as unusable:
                    reason = f"{reason}; {unusable}"
            if true_pose is None:
                skipped[path.name] = reason
                continue
            # A photo of the truth that cannot run: a miss of the run (module docstring), with its prior
            # when that is not in the photo itself (a pose file, a geotag CSV) and can be used.
            prior = prior if prior is not None or lens is not None else _prior_or_none(priors, path)
            sigma = prior.searched(fixed) if prior is not None else fixed or PriorUncertainty()
            known = {} if lens is None else {"intrinsics_source": lens.source, "distortion": lens.distortion}
            camera = lens.camera if lens is not None else None
            miss = {"unreadable" if isinstance(exc, PhotoUnreadable) else "skipped": str(exc)}
            inputs.append(PhotoInput(path.name, path, camera, prior, sigma, true_pose, **miss, **known))
            continue
        sigma = prior.searched(fixed)
        inputs.append(
            PhotoInput(
                path.name,
                path,
                camera,
                prior,
                sigma,
                true_pose,
                mask,
                depth,
                intrinsics_source=lens.source,
                distortion=lens.distortion,
                orientation=orientation,
            )
        )
    inputs = [replace(inp, later_files=_later_files(spec, intrinsics, inp.path)) for inp in inputs]
    placed = [inp for inp in inputs if inp.prior is not None]
    if store is not None and placed:
        model = flight_area(store, model, placed)
    remedy = (
        f"pass {parameter('offset', 'X,Y,Z')} (where the model's frame has its origin in that CRS), or leave "
        f"out {parameter('crs')}"
    )
    check_model_in_crs(model, offset, remedy)  # before its poses are written as CRS coordinates
    inputs = _on_the_map(spec, model, inputs, skipped)
    return Resolved(model, inputs, skipped, store)


def _on_the_map(
    spec: PhotoSpec, model: CityModel, inputs: list[PhotoInput], skipped: dict[str, str]
) -> list[PhotoInput]:
    """``inputs`` without the photos whose prior lies so far from every building that no view of their
    search can see one (``search_reach.MapLayout.off_map``, the localizer's own bound); those are added to
    ``skipped`` with the distance and where the prior came from: a prior hundreds of kilometres off (a
    photo of another place, a COLMAP quaternion in another order) is that photo's problem, said before
    anything is searched or drawn, not the run's end. One with a true pose stays, a miss with that reason
    (``PhotoInput.skipped``)."""
    if not any(inp.prior is not None for inp in inputs):
        return inputs
    layout, cfg = MapLayout.of(model), spec.localizer_config()
    kept = []
    for inp in inputs:
        far = None
        if inp.prior is not None and inp.runs:  # a miss of the truth stays one
            far = layout.off_map(model.pose_to_local(inp.prior.pose_world), cfg, inp.uncertainty)
        if far is None:
            kept.append(inp)
        elif inp.truth_world is not None:
            kept.append(replace(inp, skipped=f"{far} (its prior: {inp.prior.source})"))
        else:
            skipped[inp.name] = f"{far} (its prior: {inp.prior.source})"
    return kept


def _later_files(spec: PhotoSpec, intrinsics: IntrinsicsFiles, photo: Path) -> tuple[tuple[str, Path], ...]:
    """``PhotoInput.later_files`` of ``photo``: its intrinsics file (``IntrinsicsFiles.file_of``; none for
    ``exif``) and the mask and depth a ``files`` backend reads for it (``backend_options`` ``masks=`` /
    ``depth=``, a folder or one file; named as expected when missing)."""
    files = []
    if (calibration := intrinsics.file_of(photo)) is not None:
        files.append(("intrinsics", calibration))
    options = dict(spec.backend_options)
    backends = (
        ("mask", spec.seg_backend, "masks", mask_suffixes(spec.allow_lossy_mask)),
        ("depth", spec.depth_backend, "depth", DEPTH_SUFFIXES),
    )
    for kind, backend, option, suffixes in backends:
        if backend == "files" and options.get(option):
            where = Path(options[option])
            found = where if not where.is_dir() else _named_or_none(where, photo, suffixes, kind)
            files.append((kind, found or where / f"{photo.stem}{suffixes[0]}"))
    return tuple(files)


def _named_or_none(where: Path, photo: Path, suffixes: tuple[str, ...], kind: str) -> Path | None:
    """``perception.files.named_file`` of ``photo`` in ``where``; None when there is none or two (the
    backend says which at the photo's turn)."""
    try:
        return named_file(where, photo.name, suffixes, kind)
    except InputFileError:
        return None


RECURSIVE_REMEDY = f"pass {parameter('recursive')} to read them"


def photo_paths(spec: PhotoSpec) -> list[Path]:
    """The photos of ``spec``'s folder (``datasets.photos.list_images``; with ``spec.recursive`` its
    subfolders too, but not the run's own ``_run_folders``), without the label maps beside photos of their
    stem (``label_maps_left_out``). Two photos of one stem (``X.JPG``, ``X.png``) are refused
    (``InputFileError``, ``check_unique_stems``): every output of a photo is named by its stem, so the
    second's ``poses/X.json`` would replace the first's."""
    images = _listed_photos(spec)
    maps = label_maps_beside_photos(images)
    images = [i for i in images if i not in maps]
    check_unique_stems(Path(spec.images), images)
    return images


def label_maps_left_out(spec: PhotoSpec) -> list[Path]:
    """The label maps of ``spec``'s folder that lie beside a photo of their stem (``X.png`` beside
    ``X.JPG``, ``io.images.label_maps_beside_photos``: what ``semcityloc label --out`` into the photos'
    folder writes): no photos of the run, said before it (stop 56)."""
    return sorted(label_maps_beside_photos(_listed_photos(spec)))


def _listed_photos(spec: PhotoSpec) -> list[Path]:
    return list_images(
        spec.images,
        every_entry=True,
        recursive=spec.recursive,
        skip_dir=_run_folders(spec),
        remedy=RECURSIVE_REMEDY,
    )


def unread_subfolder_photos(spec: PhotoSpec) -> list[Path]:
    """The photos in subfolders of ``spec``'s folder that a run without ``recursive`` does not read (none
    with it): said before the run, so that a card's ``DCIM/100MEDIA/`` or a ``sub/`` of a flight is not
    left out without a word. None when its top level holds none either: ``photo_paths`` refuses that folder
    saying so."""
    top = Path(spec.images)
    if spec.recursive or not any(p.suffix.lower() in IMAGE_SUFFIXES for p in top.iterdir()):
        return []
    return subfolder_images(top, _run_folders(spec))


def _run_folders(spec: PhotoSpec) -> Callable[[Path], bool]:
    """Which subfolders of the photos' folder hold no photos of the run: its masks and depth folders and
    any run folder (one holding a ``run.json``: this run's own ``--out`` placed inside, on resume)."""
    inputs = {Path(f).resolve() for f in (spec.masks, spec.depth) if f}
    return lambda folder: folder.resolve() in inputs or (folder / RUN_FILE).is_file()


class PhotoUnreadable(PhotoMissing):
    """A photo's own input (the photo, its mask or depth) is missing, cannot be read or does not fit the
    photo: skipped, or with a true pose a miss (module docstring)."""


class TruthUnusable(PhotoMissing):
    """The truth has an entry for the photo that cannot be used (``_true_pose``): skipped, never a miss."""


def _photo_camera(intrinsics: IntrinsicsFiles, path: Path, width: int, height: int, meta) -> PhotoCamera:
    """``intrinsics.photo_camera`` of the photo ``path``; intrinsics of another image (another size, a
    principal point far off its centre: ``IntrinsicsMismatchError``) are ``PhotoUnreadable``, as a mask of
    another aspect is: that photo skipped, or with a true pose a miss, the reason naming file and sizes."""
    try:
        return intrinsics.photo_camera(path, width, height, meta)
    except IntrinsicsMismatchError as exc:
        raise PhotoUnreadable(str(exc)) from None


def _prior_or_none(priors: PriorFiles, path: Path) -> PhotoPrior | None:
    """``priors.prior`` of the unreadable photo ``path``, a miss of the run, None when there is none it can
    give (its prior may be in the photo itself); the miss's reason names the photo's own file."""
    try:
        return priors.prior(path)
    except InputFileError:  # PhotoMissing among them
        return None


def _true_pose(truth: PriorFiles | None, path: Path, meta) -> Pose | None:
    """The true pose of the photo ``path`` (world frame), None when the truth has none for it (ground truth
    is optional per photo); ``PhotoMissing`` saying so when it has one that cannot be used (a file that
    cannot be read, of another CRS, a geotag row without a usable position, DJI tags or a geotag row
    without a heading):
    that photo is skipped with the reason, not run as one without ground truth, which would leave it out of
    the recall unsaid."""
    if truth is None:
        return None
    try:
        true = truth.prior(path, meta)
        if not true.heading_known:  # a yaw of 0 taken for one the tags (or the row) lack is no true pose
            raise InputFileError(true.no_heading_truth)
        return true.pose_world
    except PhotoNotListed:
        return None
    except InputFileError as exc:
        raise TruthUnusable(
            f"its true pose cannot be used ({exc}): fix its entry in the ground truth "
            f"({parameter('truth')}), or remove it to run the photo without ground truth"
        ) from None


def _readable_photo(path: Path) -> tuple[int, int, int]:
    """(width, height, EXIF orientation) of a photo whose pixels decode (``io.images.check_decodes``, here
    with the size and orientation from the same opening: ``decoded_size_and_orientation``);
    ``PhotoMissing`` naming the file when it is not a file, is empty, truncated, corrupt or of a format
    Pillow does not read: that photo is skipped with the reason, the others run."""
    if not path.is_file():
        raise PhotoUnreadable(f"{path}: not a file (named like a photo)")
    try:
        if path.stat().st_size == 0:
            raise InputFileError(f"{path}: cannot read photo (empty file)")
        return decoded_size_and_orientation(path, "photo")
    except (InputFileError, OSError) as exc:
        raise PhotoUnreadable(str(exc)) from None


def flight_area(store: TileStore, frame: CityModel, inputs: list[PhotoInput]) -> CityModel:
    """The tiles of a store within a camera's range of any photo's prior: the map of the run's overlays
    and exports (the localizer loads its own per photo, ``localization.tiled``)."""
    xy = np.array([frame.pose_to_local(inp.prior.pose_world).center[:2] for inp in inputs])
    tiles = store.tiles_around(xy, MAX_VIEW_RANGE_M) or store.tiles_near(xy[0])
    return store.load(tiles)


def _mask_file(spec: PhotoSpec, photo: Path, camera: Camera, orientation: int) -> Path | None:
    """``_input_file`` of the photo's mask (``perception.files.find_mask``: a JPEG one too with
    ``allow_lossy_mask``), its header checked too (``io.images.check_label_header``) saying why it cannot
    be used: a lossy format without ``allow_lossy_mask`` (named ``.png``, or a JPEG beside no other mask),
    ``PhotoMissing``; not class ids, ``PhotoUnreadable``."""
    # a refusal names the spec's own allow_lossy_mask (``errors.PARAMETERS``), not the backend's allow_lossy
    find = functools.partial(find_mask, allow_lossy=spec.allow_lossy_mask, lossy_option="allow_lossy_mask")
    try:
        path = _input_file(spec.masks, photo, find, "mask", camera, orientation)
        if path is not None and path.suffix.lower() != ".npy":
            check_label_header(path, spec.allow_lossy_mask, "allow_lossy_mask")
    except LossyMaskError as exc:  # the run's --allow-lossy-mask, not this file
        raise PhotoMissing(str(exc)) from None
    except PhotoMissing:
        raise
    except InputFileError as exc:
        raise PhotoUnreadable(str(exc)) from None
    return path


def _find_depth(folder: Path, name: str) -> Path:
    """The depth file of photo ``name`` in ``folder`` (``perception.files.find_file``)."""
    return find_file(folder, name, DEPTH_SUFFIXES, "depth")


def _array_shape(path: Path) -> tuple[int, int]:
    """(H, W) of a mask / depth file from its header (PNG) or array header (``.npy``)."""
    if path.suffix.lower() == ".npy":
        try:
            shape = np.load(path, mmap_mode="r", allow_pickle=False).shape
        except (OSError, ValueError) as exc:
            raise PhotoUnreadable(f"{path}: not a readable .npy array ({exc})") from None
        return tuple(int(v) for v in shape)
    width, height = image_size(path, "mask or depth image")
    return height, width


def _input_file(
    folder: str | None,
    photo: Path,
    find: Callable[[Path, str], Path],
    what: str,
    camera: Camera,
    orientation: int,
) -> Path | None:
    """The photo's mask / depth file in ``folder`` (None without a folder; ``find(folder, photo name)``
    finds it), checked to show the photo's field of view (``orientation``: the photo's EXIF one);
    ``PhotoUnreadable`` when absent, when its header cannot be read or when it is of another aspect
    (``LossyMaskError`` as it is: the run's option, not the file)."""
    if not folder:
        return None
    try:
        path = find(Path(folder), photo.name)
    except LossyMaskError:
        raise
    except InputFileError as exc:
        raise PhotoUnreadable(str(exc)) from None
    try:
        shape = _array_shape(path)
    except InputFileError as exc:  # PhotoUnreadable (a .npy) among them
        raise PhotoUnreadable(str(exc)) from None
    try:
        check_aspect_of_photo(shape, camera.width, camera.height, what, path, orientation)
    except (InputFileError, ValueError) as exc:
        raise PhotoUnreadable(str(exc)) from None
    return path
