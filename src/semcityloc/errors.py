"""Every error the library raises on purpose, in one place.

Each is a ``SemCityLocError`` so that callers (and the CLI, which turns them into a one-line message and
exit code 2) can tell bad input from a bug.
"""

from __future__ import annotations


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


class EmptyModelError(SemCityLocError):
    """A city model with no building geometry (or none left after LoD selection)."""


class CRSError(SemCityLocError):
    """A coordinate reference system string that cannot be parsed or resolved."""


class CameraError(SemCityLocError, ValueError):
    """Invalid camera intrinsics (non-positive focal length or size, non-finite values)."""


class PoseError(SemCityLocError, ValueError):
    """Invalid pose: non-finite values, not a rotation, wrong shape."""


class ShapeError(SemCityLocError, ValueError):
    """An array argument with the wrong shape or dtype."""


class RenderError(SemCityLocError):
    """A renderer that cannot run (engine missing, model unusable)."""


class OptionalDependencyError(SemCityLocError, ImportError):
    """An optional extra is needed; the message names the pip command that installs it."""

    def __init__(self, package: str, extra: str, purpose: str):
        super().__init__(
            f"{purpose} needs the optional package '{package}': pip install 'semcityloc[{extra}]'"
        )
        self.package = package
        self.extra = extra


class ParameterError(SemCityLocError, ValueError):
    """An option or parameter out of its documented range (generator seed/blocks/lods, LoD1 height mode)."""
