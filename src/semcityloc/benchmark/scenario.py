"""Named simulation scenarios (``clean``, ``realistic``) and ``--set knob=value`` overrides.

Why: the benchmark is a proxy for real photos, so its default must be as hard as they are. A scenario is
a named bundle of knob values of ``QueryConfig`` (and of its nested ``RealityParams`` / ``DepthParams``);
every knob is documented where it is defined. ``clean`` is the first benchmark (queries almost the map
itself: kept to compare with); ``realistic`` (the default of ``semcityloc benchmark`` and the demo)
follows the paper's real data: GNSS/IMU priors as flown, a reality that differs from the map, structured
segmentation errors and non-affine depth. ``docs/benchmark.md`` gives each value and its source.

Knob names (``query_config``'s ``settings``, the command line's ``--set``; ``knob_names``): a
``QueryConfig`` field (``prior_height_m=20``) but those set by their own option (``OPTION_FIELDS``), or a
nested field by its own name when unambiguous (``shift_xy_max_m=1``) or dotted
(``reality.shift_xy_max_m=1``, ``depth_model.distortion=0.2``). Values are parsed as JSON where they can be
(``30``, ``null``, ``[2, 15]``, ``true``), else taken as strings (``zero-shot``); a pair is also accepted as
``2-15``. Each knob's type is checked where it is defined (``QueryConfig``, ``RealityParams``,
``DepthParams``): a yes/no knob by ``errors.true_or_false`` (``False``, ``no`` ...), a number knob refuses
text (``abc``, ``nan``).
"""

from __future__ import annotations

import dataclasses
import json
from typing import Any

from semcityloc.benchmark.depth_sim import DepthParams
from semcityloc.benchmark.queries import QueryConfig
from semcityloc.benchmark.reality import REALISTIC_REALITY, RealityParams
from semcityloc.errors import BenchmarkConfigError, parameter, unknown_choice

DEFAULT_SCENARIO = "realistic"

SCENARIOS: dict[str, dict[str, Any]] = {
    "clean": {},
    "realistic": {
        # GNSS/IMU as flown: horizontal 2-15 m, height +-30 m (barometric / geoid: LoD-Loc searches
        # +-30 m for this reason; both real priors in ../shared are mostly height), yaw +-8 deg,
        # roll / pitch N(0, 1 deg) clipped to +-3 deg (gimbal IMU).
        "prior_translation_m": (2.0, 15.0),
        "prior_height_m": 30.0,
        "prior_yaw_deg": 8.0,
        "prior_roll_pitch_sigma_deg": 1.0,
        "prior_roll_pitch_deg": 3.0,
        "reality": REALISTIC_REALITY,
        "seg_model": "structured",
        "depth_model": DepthParams(),
        "score_against_map": True,
    },
}


def query_config(
    scenario: str = DEFAULT_SCENARIO, settings: dict[str, Any] | None = None, **fields
) -> QueryConfig:
    """The ``QueryConfig`` of ``scenario`` with ``fields`` (queries, seed, seg_quality, ...) and the
    ``settings`` knob overrides applied (``{knob: value}``; the command line's ``--set knob=value``:
    ``cli.benchmark.parse_settings``)."""
    if scenario not in SCENARIOS:
        raise unknown_choice("scenario", scenario, SCENARIOS, BenchmarkConfigError)
    cfg = QueryConfig(**{**SCENARIOS[scenario], **fields, "scenario": scenario})
    return set_knobs(cfg, settings or {})


# ``QueryConfig`` fields that are no knob: each is set by its own option (``query_config``'s keyword, the
# command's flag), and ``scenario`` names the bundle the knobs came from.
OPTION_FIELDS = ("queries", "scenario")


def knob_names() -> tuple[str, ...]:
    """Every name ``--set`` accepts (top-level fields, then the nested ones dotted); ``resolve_knob`` reads
    this list too."""
    out = [f.name for f in dataclasses.fields(QueryConfig) if f.name not in OPTION_FIELDS]
    for outer, cls in _NESTED.items():
        out += [f"{outer}.{f.name}" for f in dataclasses.fields(cls)]
    return tuple(out)


_NESTED = {"reality": RealityParams, "depth_model": DepthParams}


def resolve_knob(name: str) -> tuple[str | None, str]:
    """(nested field or None, field name) of a knob name (module docstring), one of ``knob_names``; a field
    set by its own option (``OPTION_FIELDS``) is refused naming that option."""
    if name in OPTION_FIELDS:
        raise BenchmarkConfigError(
            f"{name} is no knob of {parameter('settings')}: give it as {parameter(name)}"
        )
    names = knob_names()
    if name not in names:  # a nested field by its own name, when only one holds it
        owners = [known for known in names if known.endswith("." + name)]
        name = owners[0] if len(owners) == 1 else name
    if name in names:
        outer, _, inner = name.rpartition(".")
        return outer or None, inner
    raise unknown_choice("knob", name, names, BenchmarkConfigError)


def parse_value(text: str) -> Any:
    """A knob value from the command line (module docstring)."""
    try:
        return json.loads(text)
    except ValueError:
        pass
    parts = text.split("-")
    if len(parts) == 2:
        try:
            return [float(parts[0]), float(parts[1])]
        except ValueError:
            pass
    return text


def _coerce(value: Any, current: Any) -> Any:
    if isinstance(value, list):
        return tuple(value)
    if isinstance(current, float) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


def set_knobs(cfg: QueryConfig, settings: dict[str, Any]) -> QueryConfig:
    """``cfg`` with every knob of ``settings`` set at once, then checked: knobs that are only valid
    together (``height_range_m`` and ``nominal_height_m``) can move together."""
    top: dict[str, Any] = {}
    nested: dict[str, dict[str, Any]] = {}
    for name, value in settings.items():
        outer, inner = resolve_knob(name)
        if outer is None:
            top[inner] = value
        else:
            nested.setdefault(outer, {})[inner] = value
    try:
        changes = {name: _coerce(value, getattr(cfg, name)) for name, value in top.items()}
        for outer, fields in nested.items():
            # e.g. depth_model in the clean scenario is None: start from the realistic defaults
            base = getattr(cfg, outer) or _NESTED[outer]()
            changes[outer] = dataclasses.replace(
                base, **{name: _coerce(value, getattr(base, name)) for name, value in fields.items()}
            )
        return dataclasses.replace(cfg, **changes)
    except (TypeError, ValueError) as exc:
        if isinstance(exc, BenchmarkConfigError):
            raise
        given = " ".join(f"{name}={value!r}" for name, value in settings.items())
        raise BenchmarkConfigError(f"{given} ({parameter('settings')}): {exc}") from exc
