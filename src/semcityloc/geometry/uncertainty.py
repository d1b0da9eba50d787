"""How far a pose prior may be off: ``PriorUncertainty``, the input the localizer's search volume follows.

Why: a GNSS/IMU prior is not equally good everywhere. An RTK-fixed drone knows its position to
centimetres, a drone on plain GNSS to metres horizontally and to tens of metres in height (barometric
altitude, geoid confusion), a gimbal IMU its roll and pitch to about a degree. The search must cover what
the prior may be off by and no more: a box too small gives a confident wrong pose at its edge, a box too
large costs time and invites look-alikes. So the uncertainty is stated (one standard deviation per
component), and the localizer searches ``n_sigma`` of it (``localization.config.SearchConfig``).

Defaults (``PriorUncertainty()``): a DJI drone on single-point GNSS with a 3-axis gimbal, the case of
both real images in ``../shared/data`` and of the benchmark's ``realistic`` priors:

- horizontal ``xy_m`` = 5 m per axis: single-point GNSS in a city (multipath near buildings) is off by
  2-15 m; 3 sigma = 15 m.
- height ``z_m`` = 10 m: DJI's "absolute altitude" without RTK is barometric or mixes ellipsoidal and
  orthometric heights; LoD-Loc searches +-30 m in height for this reason (3 sigma = 30 m). The two real
  priors are 20.7 m and about 12 m off in height.
- ``yaw_deg`` = 3 deg: compass heading near steel and concrete; 3 sigma = 9 deg.
- ``roll_pitch_deg`` = 1 deg: gimbal IMU (roll and pitch are measured against gravity).

No heading at all (no compass, a photo without one): ``yaw=60`` (``NO_HEADING_YAW_DEG``) or more; the
cascade then searches every heading, slower (``docs/localization.md``, "A prior without a heading").

With RTK (``rtk()``): the reported standard deviations, floored at ``RTK_FLOOR_M`` because a city model
is itself only good to about a metre (footprints, roof heights) and the camera-to-antenna offset and
timing add decimetres.

Parse from the command line with ``PriorUncertainty.parse("xy=5,z=15,yaw=5,rp=1")`` (any subset).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

from semcityloc.errors import ParameterError

RTK_FLOOR_M = 0.5  # a map is good to ~1 m; lever arm and timing add decimetres
# Beyond this a position is no prior for a local search (a district is a few km across): a larger sigma is
# a unit mistake or a broken tag, refused rather than searched.
MAX_POSITION_SIGMA_M = 10_000.0
# A heading not known at all (no compass; a photo without one) is stated as ``yaw=60`` or more: its 3 sigma
# (``CascadeConfig.n_sigma``) spans every heading, which the search then covers as a full circle
# (``cascade.FULL_CIRCLE_HALF_DEG``, stop 53); a larger yaw sigma says the same, up to 180.
NO_HEADING_YAW_DEG = 60.0
MAX_YAW_SIGMA_DEG = 180.0
MAX_ROLL_PITCH_SIGMA_DEG = 20.0
DEFAULT_SOURCE = "default (DJI single-point GNSS + gimbal IMU)"
# Names accepted by ``parse`` for each field.
_ALIASES = {
    "xy": "xy_m",
    "xy_m": "xy_m",
    "h": "xy_m",
    "z": "z_m",
    "z_m": "z_m",
    "height": "z_m",
    "yaw": "yaw_deg",
    "yaw_deg": "yaw_deg",
    "rp": "roll_pitch_deg",
    "roll_pitch": "roll_pitch_deg",
    "roll_pitch_deg": "roll_pitch_deg",
}


@dataclass(frozen=True)
class PriorUncertainty:
    """One-sigma error of a prior pose, per component (module docstring). ``source`` says where the
    numbers came from (defaults, the command line, the image's RTK tags, ...), for reports."""

    xy_m: float = 5.0
    z_m: float = 10.0
    yaw_deg: float = 3.0
    roll_pitch_deg: float = 1.0
    source: str = DEFAULT_SOURCE

    def __post_init__(self) -> None:
        for name in ("xy_m", "z_m", "yaw_deg", "roll_pitch_deg"):
            value = getattr(self, name)
            try:
                value = float(value)
            except (TypeError, ValueError) as exc:
                raise ParameterError(f"prior uncertainty {name} must be a number, got {value!r}") from exc
            if not math.isfinite(value) or value < 0:
                raise ParameterError(f"prior uncertainty {name} must be finite and >= 0, got {value!r}")
            object.__setattr__(self, name, value)
        if max(self.xy_m, self.z_m) > MAX_POSITION_SIGMA_M:
            raise ParameterError(
                f"prior uncertainty xy {self.xy_m:g} m / z {self.z_m:g} m is too large for a local search "
                f"(at most {MAX_POSITION_SIGMA_M:g} m each): a prior that poor is no prior"
            )
        if self.yaw_deg > MAX_YAW_SIGMA_DEG or self.roll_pitch_deg > MAX_ROLL_PITCH_SIGMA_DEG:
            raise ParameterError(
                f"prior uncertainty yaw {self.yaw_deg:g} deg / roll-pitch {self.roll_pitch_deg:g} deg is too "
                f"large for a local search (yaw <= {MAX_YAW_SIGMA_DEG:g}: {NO_HEADING_YAW_DEG:g} or more "
                f"searches every heading; roll/pitch <= {MAX_ROLL_PITCH_SIGMA_DEG:g} deg)"
            )

    @classmethod
    def parse(cls, text: str, base: PriorUncertainty | None = None) -> PriorUncertainty:
        """``"xy=5,z=15,yaw=5,rp=1"`` (any subset, the rest from ``base`` or the defaults)."""
        base = base or cls()
        values: dict[str, float] = {}
        for part in str(text).split(","):
            part = part.strip()
            if not part:
                continue
            key, sep, value = part.partition("=")
            key = key.strip().lower()
            if not sep or key not in _ALIASES:
                raise ParameterError(
                    f"prior uncertainty {part!r}: expected KEY=VALUE with KEY one of xy, z, yaw, rp "
                    "(e.g. xy=5,z=15,yaw=5,rp=1)"
                )
            if _ALIASES[key] in values:
                raise ParameterError(f"prior uncertainty {text!r}: {key} is given twice; give each key once")
            try:
                values[_ALIASES[key]] = float(value)
            except ValueError as exc:
                raise ParameterError(f"prior uncertainty {part!r}: {value!r} is not a number") from exc
        if not values:
            raise ParameterError("prior uncertainty: nothing given (e.g. xy=5,z=15,yaw=5,rp=1)")
        return replace(base, **values, source="given")

    @classmethod
    def rtk(
        cls, std_xy_m: float | None = None, std_z_m: float | None = None, base: PriorUncertainty | None = None
    ) -> PriorUncertainty:
        """An RTK-fixed position: the reported standard deviations (None: ``RTK_FLOOR_M``), floored at
        ``RTK_FLOOR_M``; orientation from ``base`` (defaults)."""
        base = base or cls()
        xy = max(RTK_FLOOR_M, float(std_xy_m) if std_xy_m is not None else 0.0)
        z = max(RTK_FLOOR_M, float(std_z_m) if std_z_m is not None else 0.0)
        return replace(base, xy_m=xy, z_m=z, source="RTK fixed (image metadata)")

    def scaled(self, factor: float) -> PriorUncertainty:
        """Every component times ``factor`` (e.g. a wider search for a poor prior)."""
        return replace(
            self,
            xy_m=self.xy_m * factor,
            z_m=self.z_m * factor,
            yaw_deg=self.yaw_deg * factor,
            roll_pitch_deg=self.roll_pitch_deg * factor,
        )

    def without_heading(self) -> PriorUncertainty:
        """This uncertainty for a prior whose heading is unknown (a photo whose tags have none): its yaw
        sigma at least ``NO_HEADING_YAW_DEG``, so that every heading is searched whatever yaw the prior holds
        (a smaller one, stated or a default, would search around an arbitrary heading); the reason added to
        ``source``. The one rule of "no heading", whatever gave the other sigmas."""
        return replace(
            self,
            yaw_deg=max(self.yaw_deg, NO_HEADING_YAW_DEG),
            source=f"{self.source}; no heading in the prior: every heading searched",
        )

    def as_dict(self) -> dict:
        """The sigmas and their source as a plain dict, for run records."""
        return asdict(self)

    def describe(self) -> str:
        """One line for messages: each 1-sigma with its unit, and where it came from."""
        return (
            f"xy {self.xy_m:g} m, z {self.z_m:g} m, yaw {self.yaw_deg:g} deg, roll/pitch "
            f"{self.roll_pitch_deg:g} deg (1 sigma; {self.source})"
        )
