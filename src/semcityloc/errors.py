"""Every error the library raises on purpose, in one place, and the helpers that word user messages.

Each is a ``SemCityLocError`` so that callers (and the CLI, which turns them into a one-line message and
exit code 2) can tell bad input from a bug.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import TypeVar


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


class CRSError(SemCityLocError):
    """A coordinate reference system string that cannot be parsed or resolved."""


class CameraError(SemCityLocError, ValueError):
    """Invalid camera intrinsics (non-positive focal length or size, non-finite values)."""


class IntrinsicsMismatchError(CameraError):
    """Intrinsics from a file that describe another image than the photo they are used with (another size
    that is no resize of it, a principal point far off its centre): the message names the file, the photo
    and both sizes. ``semcityloc run`` skips that photo (with a true pose: a miss), ``localize`` stops."""


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
