"""The tuning discipline in one place: which cities a knob, a preset or a fitted model may be chosen on.

Why: a method tuned on the city it is reported on is measured on its own training data. Every knob of
the localizer and every fitted model (the confidence model, the simulated segmentation's presets) is
chosen on the *calibration cities* only, the generated district and Fürth (``../shared/data``), and
reported on the others (Berlin, Den Haag, the real images). The tuning scripts in ``benchmarks/``
(``compare_configs``, ``calibrate_confidence``, ``calibrate_segmentation``) take their default cities
from ``calibration_cities`` and refuse any other city as a place to choose with
``require_calibration_cities``.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from semcityloc.benchmark.spec import GENERATED, resolve_city
from semcityloc.errors import InputFileError, ParameterError

# Fürth's LoD2 district, relative to the shared data folder (``../shared/data`` beside the repository).
FUERTH_FILE = Path("fuerth_lod2_citygml1") / "LOD2_4424_5482_solid.gml"


def calibration_cities(shared_data: Path) -> list[str]:
    """The calibration cities: the generated district, and Fürth when ``shared_data`` holds it."""
    fuerth = Path(shared_data) / FUERTH_FILE
    return [GENERATED, str(fuerth)] if fuerth.is_file() else [GENERATED]


def is_calibration_city(city: str | Path, shared_data: Path) -> bool:
    """Does ``city`` (``"generated"``, a file or a tile store) name a calibration city? Files are compared
    resolved, so a relative path or a symlink to Fürth counts; an unknown path does not."""
    if str(city) == GENERATED:
        return True
    try:
        target = resolve_city(city)
    except InputFileError:
        return False
    known = {resolve_city(c) for c in calibration_cities(shared_data)}
    return target in known


def require_calibration_cities(cities: Iterable[str | Path], shared_data: Path, purpose: str) -> None:
    """``ParameterError`` naming the first city that is not a calibration city: ``purpose`` says what
    would have been chosen there (``"tune a knob"``, ``"fit the confidence model"``)."""
    for city in cities:
        if not is_calibration_city(city, shared_data):
            raise ParameterError(
                f"{city} is not a calibration city (the generated district, Fürth): do not {purpose} on a "
                "city that results are reported on"
            )
