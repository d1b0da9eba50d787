"""Every error the library raises on purpose, in one place, and the helpers that word user messages.

Each is a ``SemCityLocError`` so that callers (and the CLI, which turns them into a one-line message and
exit code 2) can tell bad input from a bug.

A message that asks its reader to pass something names it through ``parameter``: as a Python caller passes
it (``crs='EPSG:25832'``, ``prior_uncertainty=PriorUncertainty.parse('z=8')``), since the library's caller
passed no command-line flag. The command line turns each such spelling into its flag when it prints
(``as_flags``: ``--crs EPSG:25832``, ``--prior-sigma z=8``), and so does a run folder's every file
(``benchmark``). ``PARAMETERS`` holds both spellings of each, once.
"""

from __future__ import annotations

import math
import numbers
import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any, TypeVar


class SemCityLocError(Exception):
    """Base class of all errors raised on purpose by semcityloc."""


class InputFileError(SemCityLocError):
    """A file that cannot be used: missing, unreadable, of an unknown format."""


class MalformedXMLError(InputFileError):
    """Not XML, truncated XML, or XML that refers to entities/DTDs we refuse to resolve."""


class UnsupportedFormatError(InputFileError):
    """A well-formed file whose root element, version or format we do not read."""


class MalformedCityJSONError(InputFileError):
    """CityJSON that is not valid JSON or breaks the CityJSON structure."""


class LossyMaskError(InputFileError):
    """A label mask in a lossy format (JPEG, WebP) without the flag that forces it: a choice the whole run
    shares (every mask of a folder has one format), so a data-set benchmark refuses the run in one line
    naming the flag instead of counting each query a miss."""


class EmptyModelError(SemCityLocError):
    """A city model with no building geometry (or none left after LoD selection)."""


class LodNotHeldError(EmptyModelError):
    """A city model (or tile) whose buildings hold no geometry at the LoD asked for; ``present``: the LoDs
    it does hold, as the message says them (``"1, 2"``). A tile store's build refuses such tiles rather
    than leaving them out (``citymodel.tiles.build_store``): they are not malformed, and left out they would
    be holes in the city."""

    def __init__(self, message: str, present: str = ""):
        super().__init__(message)
        self.present = present


class CRSError(SemCityLocError):
    """A coordinate reference system string that cannot be parsed or resolved."""


class CameraError(SemCityLocError, ValueError):
    """Invalid camera intrinsics (non-positive focal length or size, non-finite values)."""


class IntrinsicsMismatchError(CameraError):
    """Intrinsics from a file that describe another image than the photo they are used with (another size
    that is no resize of it, a principal point far off its centre): the message names the file, the photo
    and both sizes. ``semcityloc run`` skips that photo (with a true pose: a miss), ``localize`` stops."""


class UnknownImageSizeError(CameraError):
    """Intrinsics that state no image size and whose principal point does not give one (not at the centre of
    a whole-pixel image): the caller says how to give the size (``semcityloc localize``: ``--image``, or
    ``--width`` / ``--height``)."""


class PoseError(SemCityLocError, ValueError):
    """Invalid pose: non-finite values, not a rotation, wrong shape."""


class ShapeError(SemCityLocError, ValueError):
    """An array argument with the wrong shape or dtype."""


class ArgumentTypeError(SemCityLocError, TypeError):
    """An argument of the wrong kind: a path where a ``CityModel`` is wanted, a matrix where a ``Pose`` is."""


class RenderError(SemCityLocError):
    """A renderer that cannot run (engine missing, model unusable)."""


class OptionalDependencyError(SemCityLocError, ImportError):
    """An optional extra is needed; the message names the pip command that installs it (``command``, when
    the extra alone does not: a package installed on its own, e.g. with ``--no-deps``)."""

    def __init__(self, package: str, extra: str, purpose: str, command: str | None = None):
        super().__init__(
            f"{purpose} needs the optional package '{package}': "
            + (command or f"pip install 'semcityloc[{extra}]'")
        )
        self.package = package
        self.extra = extra


class ParameterError(SemCityLocError, ValueError):
    """An option or parameter out of its documented range (generator seed/blocks/lods, LoD1 height mode)."""


class MissingWeightsError(InputFileError):
    """Model weights that are not on this machine; the message says what to download and where to put it."""


class BenchmarkConfigError(SemCityLocError, ValueError):
    """A query configuration value out of its range."""


class QuerySimulationError(SemCityLocError):
    """A query that cannot be simulated at all (every attempt put the camera under the model)."""


class PerceptionSimError(SemCityLocError, ValueError):
    """An unknown segmentation preset (bad arrays raise ``ShapeError``)."""


class BenchmarkError(ParameterError):
    """A benchmark request that cannot run: unknown method or preset, bad option, unusable output folder."""


class ResumeMismatchError(BenchmarkError):
    """The output folder holds a run made with other arguments."""


class RunLockedError(BenchmarkError):
    """The output folder is in use by another run that is still going (its lock file names the pid)."""


class RunFileError(BenchmarkError, InputFileError):
    """A file of a run folder that is there but cannot be read (``results.csv`` unreadable, a folder, or
    bytes that are no UTF-8 text): the message says "cannot read", names the file and what to do."""


class OutputPathError(SemCityLocError):
    """An output path that cannot be written (its parent is a file, it is a file where a folder is needed,
    or its folder is read-only or immutable); checked before any work. Also an output that fails mid-run
    (a full disk, a folder made read-only): the message names the file, the cause and the rows kept."""


_E = TypeVar("_E", bound=Exception)


def unknown_choice(what: str, name: object, known: Iterable[object], error: type[_E] = ParameterError) -> _E:
    """The error for a name that is not among the valid choices: "unknown {what} {name!r}; known: a, b, c".

    ``what`` names the kind of thing ("localizer preset", "render engine"), ``known`` the valid names in
    the order to show them ("none" when there are none). ``name`` may be a list or tuple of several
    unknown names (shown as ``'a', 'b'``). Returns the exception for ``raise unknown_choice(...)``;
    ``error`` is its class (default ``ParameterError``; a narrower one where a module has its own).
    """
    names = ", ".join(repr(n) for n in name) if isinstance(name, (list, tuple)) else repr(name)
    return error(f"unknown {what} {names}; known: {', '.join(str(k) for k in known) or 'none'}")


def counted(n: int, noun: str, plural: str | None = None) -> str:
    """``n`` and its noun for a user message: ``"1 photo"``, ``"3 photos"``, ``"0 queries"`` (``plural``:
    the plural when it is not the noun + ``s``; a noun in ``y`` after a consonant takes ``ies``). Why: a
    count is printed in many places and "1 photos" reads as a slip."""
    if n == 1:
        return f"{n} {noun}"
    if plural is None:
        plural = noun[:-1] + "ies" if noun.endswith("y") and noun[-2:-1] not in "aeiou" else noun + "s"
    return f"{n} {plural}"


TRUE_WORDS = ("true", "yes", "on", "1")  # what a yes/no setting given as text accepts as yes, in any case
FALSE_WORDS = ("false", "no", "off", "0")  # ... and as no


def finite_number(value: object) -> bool:
    """Whether a setting's ``value`` is a real, finite number: numpy's too, but no bool (``True`` is 1 to
    Python), no text (``"12"`` from ``--set`` iterates as a pair) and no NaN or infinity. The one test the
    simulation's settings (``RealityParams``, ``DepthParams``) put a number through before its range."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)


def true_or_false(value: object, name: str, error: type[_E] = ParameterError) -> bool:
    """A yes/no setting as a bool: a bool (numpy's too), the integer 0 or 1, or text among ``TRUE_WORDS`` /
    ``FALSE_WORDS`` in any case (``--set depth=False``, ``--backend-option allow_lossy=no``); anything else
    is ``error``: "{name} must be true or false, got {value!r}". Why one rule: ``bool("False")`` is True,
    and a knob whose text was taken so ran the opposite of what was asked (stop 56 audit)."""
    if isinstance(value, bool):
        return value
    numpy_bool = getattr(getattr(value, "dtype", None), "kind", "") == "b" and getattr(value, "ndim", 1) == 0
    if numpy_bool or (isinstance(value, numbers.Integral) and value in (0, 1)):
        return bool(value)  # numpy's bool (this module imports no numpy), 0, 1
    if isinstance(value, str) and value.strip().lower() in TRUE_WORDS + FALSE_WORDS:
        return value.strip().lower() in TRUE_WORDS
    raise error(f"{name} must be true or false, got {value!r}")


SHOWN_NAMES = 5  # names in a one-line message (photos in a warning), then "(+N more)"


def shown_names(names: list[str], shown: int = SHOWN_NAMES) -> str:
    """The first ``shown`` of ``names`` for a one-line message, then how many more: ``"a, b, c (+2 more)"``.
    Why here: every layer names files, photos and folders in its messages, one wording for all."""
    more = len(names) - shown
    return ", ".join(names[:shown]) + (f" (+{more} more)" if more > 0 else "")


@dataclass(frozen=True)
class Parameter:
    """Something a message asks its reader to pass, spelled twice: ``python`` as a Python caller passes it
    (the keyword of the function that said it: ``"crs='{}'"``) and ``flag`` as the command line's option
    (``"--crs {}"``); ``{}`` stands for the value, in both or in neither (then a value given is not
    shown)."""

    python: str
    flag: str


# Each parameter a message of the library names (``parameter``), with its flag (``as_flags``). An entry
# whose Python spelling holds another's comes first, as ``as_flags`` turns them in this order.
PARAMETERS: dict[str, Parameter] = {
    "store_lod": Parameter("build_store(..., lod={})", "'semcityloc tiles build ... --lod {}'"),
    "store_crs": Parameter("build_store(..., crs='{}')", "'semcityloc tiles build ... --crs {}'"),
    "store_again": Parameter(
        "build_store(TILES, STORE, overwrite=True)", "'semcityloc tiles build TILES --out STORE --overwrite'"
    ),
    "train_segmenter": Parameter(
        "train_segmenter(...)",
        "'semcityloc train-segmenter --images DIR --labels DIR --backbone ... --out DIR'",
    ),
    "store_build": Parameter("build_store(TILES, STORE)", "'semcityloc tiles build TILES --out STORE'"),
    "warmup": Parameter("semcityloc.benchmark.warmup.warm_up()", "'semcityloc warmup'"),
    "label": Parameter("auto_label(model, camera, pose_world)", "'semcityloc label'"),
    "localize_one": Parameter("Localizer.localize(query)", "'semcityloc localize --image'"),
    "undistorting": Parameter("PhotoSpec(...)", "'semcityloc run' / 'semcityloc localize'"),
    "dinov3": Parameter(
        "seg_backend='dinov3-dpt', backend_options=(('backbone', DINOV3_DIR), ('head', HEAD_DIR))",
        "--seg-backend dinov3-dpt --backend-option backbone=DINOV3_DIR --backend-option head=HEAD_DIR",
    ),
    "moge2": Parameter(
        "depth_backend='moge2', backend_options=(('model', MOGE2_MODEL_PT),)",
        "--depth-backend moge2 --backend-option model=MOGE2_MODEL_PT",
    ),
    "seg_backend": Parameter("seg_backend='{}'", "--seg-backend {}"),
    "depth_backend": Parameter("depth_backend='{}'", "--depth-backend {}"),
    "masks": Parameter("masks='{}'", "--masks {}"),
    "depth": Parameter("depth='{}'", "--depth {}"),
    "train_backbone": Parameter("train_segmenter(backbone='{}')", "train-segmenter --backbone {}"),
    "backbone": Parameter("get_segmentation_backend(..., backbone={})", "--backend-option backbone={}"),
    "head": Parameter("get_segmentation_backend(..., head={})", "--backend-option head={}"),
    "pose_name": Parameter("read_pose(..., name='{}')", "--pose-name {}"),  # one pose of a multi-image file
    "crs": Parameter("crs='{}'", "--crs {}"),
    "lod": Parameter("load_city_model(..., lod={})", "--lod {}"),
    "engine": Parameter("engine='{}'", "--engine {}"),  # a Renderer's
    "target_crs": Parameter("target_crs='{}'", "--crs {}"),
    "prior_sigma": Parameter("prior_uncertainty=PriorUncertainty.parse('{}')", "--prior-sigma {}"),
    "offset": Parameter("offset=({})", "--offset {}"),  # PhotoSpec(offset=(x, y, z))
    "target_height": Parameter("target_height='{}'", "--target-height {}"),
    "geoid_separation": Parameter("geoid_separation_m={}", "--geoid-separation {}"),
    "city": Parameter("city='{}'", "--city {}"),
    "frame": Parameter("frame='{}'", "--frame {}"),
    # What a caller of ``Localizer.localize`` sets to give a camera's calibrated focal lengths (a photo run
    # its ``PhotoSpec``'s intrinsics file): before ``intrinsics``, whose spelling it holds.
    "calibrated_camera": Parameter(
        "camera=Camera(fx=..., fy=..., ...) from the calibration, or PhotoSpec(intrinsics='FILE')",
        "--intrinsics FILE",
    ),
    "intrinsics": Parameter("intrinsics='{}'", "--intrinsics {}"),
    "priors": Parameter("priors='{}'", "--priors {}"),
    "allow_lossy": Parameter("allow_lossy=True", "--allow-lossy-mask"),
    "out": Parameter("out='{}'", "--out {}"),
    "overwrite": Parameter("overwrite=True", "--overwrite"),
    "recursive": Parameter("PhotoSpec(recursive=True)", "--recursive"),
    "calibrate_focal": Parameter("PhotoSpec(calibrate_focal='{}')", "'semcityloc run --calibrate-focal {}'"),
    "preset": Parameter("config='{}'", "--preset {}"),  # a ``LocalizerConfig`` preset by name
    # A run's spec (``PhotoSpec``, ``DatasetSpec``) and ``run_benchmark``: what a run folder's files and
    # notes ask for (``benchmark``).
    "run_prior_sigma": Parameter("prior_sigma='{}'", "--prior-sigma {}"),  # a spec's, not the Localizer's
    "allow_lossy_mask": Parameter("allow_lossy_mask=True", "--allow-lossy-mask"),
    "perception": Parameter("perception='{}'", "--perception {}"),
    "truth": Parameter("truth='{}'", "--truth {}"),
    "keep_details": Parameter("keep_details={}", "--keep-details {}"),
    "out_dir": Parameter("out_dir='{}'", "--out {}"),
    "executor": Parameter("executor='{}'", "--executor {}"),
    "ray_address": Parameter("ray_address='{}'", "--ray-address {}"),
    "settings": Parameter("settings={}", "--set {}"),  # ``scenario.query_config``'s knobs
    "prior_extra": Parameter("QueryConfig(prior_extra_m=({}))", "--prior-extra {}"),  # named bare
    # ``scenario.query_config``'s own keywords (``scenario.OPTION_FIELDS``), no knobs
    "queries": Parameter("query_config(..., queries={})", "--queries {}"),
    "scenario": Parameter("query_config(scenario='{}')", "--scenario {}"),
    "limit": Parameter("run_benchmark(..., limit={})", "--stop-after {}"),
    # ``train_segmenter``'s settings (``TrainConfig``) and its own keywords
    "lr": Parameter("TrainConfig(lr={})", "--lr {}"),
    "epochs": Parameter("TrainConfig(epochs={})", "--epochs {}"),
    "train_classes": Parameter("TrainConfig(classes='{}')", "--classes {}"),
    "input_size": Parameter("TrainConfig(input_size='{}')", "--input-size {}"),
    "val_fraction": Parameter("split_samples(..., val_fraction={})", "--val-fraction {}"),
    "resume": Parameter("train_segmenter(..., resume=True)", "--resume"),
}


def _python_bare(entry: Parameter) -> str:
    """``entry`` named without a value: ``crs=...``, ``prior_uncertainty=...``, ``build_store(..., lod=...)``
    (a keyword's name alone when the spelling starts with it)."""
    keyword = re.match(r"\w+=", entry.python)
    if keyword and "{}" in entry.python:
        return keyword.group() + "..."
    return entry.python.replace("'{}'", "...").replace("{}", "...")


def parameter(name: str, value: object = None) -> str:
    """How a message names the parameter ``name`` of ``PARAMETERS``: as a Python caller passes it, with
    ``value`` (``parameter("crs", "EPSG:25832")`` is ``crs='EPSG:25832'``) or without one (``crs=...``).
    What the command line prints has the flag instead (``as_flags``). Why: a library caller passed no
    flag, and a command-line user no keyword; the words of the message are the same for both."""
    entry = PARAMETERS[name]
    return _python_bare(entry) if value is None else entry.python.replace("{}", str(value))


def _flag_bare(entry: Parameter) -> str:
    return entry.flag.replace(" {}", "").replace("{}", "...")


def _value_pattern(tail: str) -> str:
    """What a value may hold before ``tail``, the template's rest: a quoted one anything but the quote, one
    before a closing parenthesis anything but that, a last one no space or punctuation."""
    if tail.startswith("'"):
        return r"[^']*"
    if tail.startswith(")"):
        return r"[^)]*"
    return r"[^\s,;()]+"


def _flag_patterns() -> list[tuple[re.Pattern[str], Callable[[re.Match[str]], str]]]:
    """(pattern, replacement) per spelling of ``PARAMETERS``: without a value, then with one."""
    out: list[tuple[re.Pattern[str], Callable[[re.Match[str]], str]]] = []
    start = r"(?<![\w.-])"  # a whole spelling: not the end of a longer name (``target_crs=`` is no ``crs=``)
    for entry in PARAMETERS.values():
        bare = _flag_bare(entry)  # first: ``geoid_separation_m=...`` is no value "..."
        out.append((re.compile(start + re.escape(_python_bare(entry))), lambda m, flag=bare: flag))
        if "{}" in entry.python:
            head, _, tail = entry.python.partition("{}")
            pattern = re.compile(start + re.escape(head) + f"({_value_pattern(tail)})" + re.escape(tail))
            out.append((pattern, lambda m, flag=entry.flag: flag.replace("{}", m.group(1))))
    return out


_FLAG_PATTERNS = _flag_patterns()
_T = TypeVar("_T")


def as_flags(text: _T) -> _T:
    """``text`` with each parameter a message names (``parameter``) spelled as the command line's flag:
    ``crs='EPSG:25832'`` becomes ``--crs EPSG:25832``, ``prior_uncertainty=...`` ``--prior-sigma``. A dict,
    list or tuple is turned through (keys too); anything but text is returned as it is, and text turned
    already stays as it is. What ``cli.main`` prints goes through it, and a run folder's files
    (``benchmark.results.make_row``, ``benchmark.run``)."""
    if isinstance(text, str):
        for pattern, flag in _FLAG_PATTERNS:
            text = pattern.sub(flag, text)  # type: ignore[assignment]
        return text
    if isinstance(text, dict):
        said: dict[Any, Any] = {as_flags(k): as_flags(v) for k, v in text.items()}
        return said  # type: ignore[return-value]
    if isinstance(text, list):
        return [as_flags(v) for v in text]  # type: ignore[return-value]
    if isinstance(text, tuple):
        return tuple(as_flags(v) for v in text)  # type: ignore[return-value]
    return text
