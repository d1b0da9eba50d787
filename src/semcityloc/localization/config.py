"""Named configuration presets of the localizer (hloc-style: a dict of named, documented presets).

Every number the search uses lives here; ``LocalizerConfig.preset(name)`` returns a preset (frozen: tweak
it with ``dataclasses.replace``), and ``config_or_preset`` turns what a localizer's ``config`` argument may
be (a config, a preset's name, None) into a config.

Two searches share the refinement and the scores:

- ``search="cascade"`` (the default, issue 13): the search volume follows the prior's stated
  uncertainty (``geometry.uncertainty.PriorUncertainty``, ``n_sigma`` of it per component); a sweep of
  the whole volume at low resolution (``SweepConfig``), extended when its best cell lies on the volume's
  edge; local grids at a finer resolution with roll and pitch samples around the sweep's best distinct
  cells (``LocalConfig``); one particle filter seeded by the best distinct local hypotheses, and a
  narrow polish of its best particle (``RefineConfig``); a calibrated confidence decides acceptance.
- ``search="grid"`` (the first design, preset ``legacy``): one uniform 4D grid of fixed size around the
  prior (``CoarseConfig``), roll and pitch held at the prior's, the best cells seeding one particle
  filter, hand-set acceptance thresholds. Kept to measure the new design against on the same queries.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields, is_dataclass, replace

import numpy as np

from semcityloc.errors import ParameterError, unknown_choice
from semcityloc.geometry.uncertainty import PriorUncertainty

SEARCHES = ("cascade", "grid")
ACCEPTANCES = ("calibrated", "thresholds")
# ``LocalizerConfig.map_eaves_flat_roofs``: eaves on the map's flat roofs per view, always, or never.
FLAT_EAVES = ("auto", "on", "off")
DEPTH_COSTS = ("affine", "robust")
PIVOTS = ("none", "polish", "both")


@dataclass(frozen=True)
class CoarseConfig:
    """Uniform 4D grid centred on the prior: ``range_*`` is the full width (paper: e_c), ``n_*`` the
    number of samples per axis (paper: n_c); samples are prior - range/2 ... prior + range/2."""

    range_xy_m: float = 32.0
    range_z_m: float = 16.0
    range_yaw_deg: float = 18.0
    n_xy: int = 13
    n_z: int = 7
    n_yaw: int = 13
    width: int = 64  # coarse render / mask resolution (the query mask is downsampled to it)
    height: int = 48
    top_k: int = 8  # best cells kept to seed the refinement (the best one is the coarse pose)
    # Focal of the one wide render per camera centre relative to the coarse camera's (see coarse.py).
    wide_oversample: float = 1.0

    @property
    def hypotheses(self) -> int:
        """Cells of the coarse lattice (x, y, z, yaw): the poses one coarse sweep scores."""
        return self.n_xy * self.n_xy * self.n_z * self.n_yaw


@dataclass(frozen=True)
class SweepConfig:
    """Stage 1 of the cascade: a lattice over the whole search volume at a low resolution. Steps are the
    lattice spacing; when the volume needs more than ``max_centres`` camera centres, the xy and z steps
    grow together so that it does not (time stays bounded however wide the prior). ``width`` x ``height``:
    the pixel budget of its renders, exact for a 4:3 camera; another aspect gets as many pixels in its own
    shape (``localize._scaled``)."""

    width: int = 32
    height: int = 24
    # Steps and ``keep`` measured on the calibration cities (realistic, 400 queries, seeds 0-1; with
    # polish_particles 48), R@2m,2deg / 5m,5deg: 3 m and keep 8 (stop 22) 91.5 / 99.2 %; 4 m, keep 8 or
    # 6 91.5 / 99.8 % (8 gained, 8 lost at 2 m; keep 6 gave the same poses); 5 m 90.5 / 99.5 %.
    # 4 m and keep 6 score 8,019 + 7,290 hypotheses (729 + 162 renders) instead of 11,979 + 9,720
    # (1,089 + 216).
    step_xy_m: float = 4.0
    step_z_m: float = 7.5
    step_yaw_deg: float = 2.0
    max_centres: int = 2000
    keep: int = 6  # best distinct cells (greedy non-maximum suppression on the lattice) passed on
    nms_radius: int = 1  # lattice cells around a kept cell that are not kept again
    # Best cell on the volume's edge: grow the volume by ``extension`` x its initial half-width in that
    # direction, at most ``max_extensions`` times; still on the edge after that -> not_localized.
    extension: float = 0.5
    max_extensions: int = 2


@dataclass(frozen=True)
class LocalConfig:
    """Stage 2 of the cascade: around each kept sweep cell, a small grid at a finer resolution that
    also samples roll and pitch. Offsets span +-half a sweep step in x, y, z and +-1 sweep step in yaw.
    ``width`` x ``height``: its pixel budget (as the sweep's); the refinement scores at ``RefineConfig.scale``
    times it."""

    width: int = 64
    height: int = 48
    n_xy: int = 3
    n_z: int = 3
    n_yaw: int = 5
    # Roll / pitch samples: offsets in {-s, 0, +s} on each with s = roll_pitch_sigmas x the prior's sigma
    # (0: roll and pitch stay at the prior's, as in the paper's 4D volume).
    roll_pitch_sigmas: float = 1.5
    keep: int = 8  # distinct hypotheses that seed the refinement
    distinct_xy_m: float = 2.0  # two hypotheses closer than this (and ...)
    distinct_z_m: float = 3.0
    distinct_yaw_deg: float = 2.0  # (... and this) are the same one


@dataclass(frozen=True)
class BeyondConfig:
    """Why a pose was refused: the look beyond the search's reach (``cascade.look_beyond``), run on refused
    results only. A ring of camera centres in x/y just outside the volume's largest extension, scored like
    the sweep; a view there, distinct from the refused pose, that scores higher than the sweep's best
    hints that the prior is further off than its stated uncertainty: the refusal's warning says so and
    names the ``--prior-sigma`` that would search there. Never changes an accepted pose (refusing with it
    was measured and not kept: ``docs/localization.md``, "A look beyond the volume")."""

    enabled: bool = True
    factor_xy: float = 3.0  # the ring's outer half-width in x/y, in the volume's stated half-widths
    factor_z: float = 2.0  # its z half-width, likewise (the sweep reaches 2 in z too: the ring is in x/y)
    max_centres: int = 750  # camera centres of the whole box (the ring is scored, the inside skipped)
    exclude_m: float = 12.0  # ring cells nearer than this (x/y) to the pose found are the same view
    margin: float = 0.0  # the hint when the ring's best >= the sweep's best + margin


@dataclass(frozen=True)
class LookalikeConfig:
    """The acceptance's look for a look-alike (``lookalike.py``, stop 52): in a neighbourhood of equal
    houses the view one house along scores as high as the truth, and the refinement's own margins
    (``hypothesis_margin``: hypotheses about 2 m apart, before refinement) never see it. So the best other
    peak of the sweep, more than ``min_distance_m`` from the pose found, is refined too (a local grid; the
    pose found moved there, an x/y grid of ``grid`` x ``grid`` centres ``grid_half_m`` around it, a small
    filter of ``particles`` x ``iterations`` and the polish: ``Refiner.refine_lookalike``), and scored as
    the pose was. The look-alike margin is the pose's final score minus
    that one's (``result.confidence["lookalike_margin"]``; NaN when none stays more than ``min_distance_m``
    / ``min_rotation_deg`` away); an accepted pose whose margin is below ``min_margin`` is refused as
    ambiguous (``result.REASON_AMBIGUOUS``). Off by default (the ``lookalikes`` preset turns it on): on
    held-out Berlin it refused three right poses (0.7-3.3 m off) and no wrong one (docs/localization.md)."""

    enabled: bool = False
    min_distance_m: float = 5.0  # a look-alike lies farther than this from the pose (horizontally) ...
    min_rotation_deg: float = 5.0  # ... or is turned by more than this, after its own refinement
    grid: int = 9  # the look-alike's place: grid x grid camera centres ...
    grid_half_m: float = 2.0  # ... +-this around the local grid's best (the local grid's spacing)
    particles: int = 48
    iterations: int = 4
    # Refuse an accepted pose whose look-alike margin is below this. Chosen on the calibration cities by a
    # rule written first (docs/localization.md, "Look-alikes"): the largest of 0.005-0.05 refusing at most
    # 1 % of their right poses (generated + Fürth, seeds 0-1, 200 queries: none refused at 0.05; the
    # smallest right pose's margin 0.19); on three repetitive cities of our own (make_rows.py, seeds 0-2,
    # 270 queries) it refuses 35 of 41 wrong accepted poses and 99 of 207 right ones (views as ambiguous).
    min_margin: float = 0.05


@dataclass(frozen=True)
class CascadeConfig:
    """The default search (``search="cascade"``): how large its volume is and how each stage samples it.

    The volume's half-widths are ``n_sigma`` times the prior's stated uncertainty, with floors so that even an
    RTK prior leaves room for the map's own errors, and a floor of the camera's height above the ground
    (``min_clearance_m``). The stages' own settings are the nested configs: the low-resolution ``sweep`` of
    the whole volume, the finer ``local`` grids around its best cells, and the ``beyond`` ring that hints a
    prior further off than stated. Kept apart from ``CoarseConfig`` (the first design's fixed grid) so that
    both searches can be run on the same queries.
    """

    sweep: SweepConfig = field(default_factory=SweepConfig)
    local: LocalConfig = field(default_factory=LocalConfig)
    beyond: BeyondConfig = field(default_factory=BeyondConfig)
    lookalike: LookalikeConfig = field(default_factory=LookalikeConfig)
    n_sigma: float = 3.0  # the volume's half-width in units of the prior's sigma
    # Floors of the half-widths, so that an RTK prior still leaves room for the map's own errors.
    min_half_xy_m: float = 3.0
    min_half_z_m: float = 3.0
    min_half_yaw_deg: float = 3.0
    # The volume's floor: no camera centre lower than this above the lowest ground near the prior
    # (``cascade.search_volume``); -inf in ``ground_z`` (a model without buildings) leaves it open.
    min_clearance_m: float = 5.0


@dataclass(frozen=True)
class RefineConfig:
    """One particle filter seeded by the search's best hypotheses (half of the particles around the best,
    the rest spread over the others). Perturbation scales shrink by ``shrink`` per iteration.

    Measured on the calibration cities (Fürth, generated; realistic, 400 queries): a filter per
    hypothesis followed by a polish of the best (40 x 5 each, then 96 x 5) reached 82 % at 2 m / 2 deg
    where this one filter over 8 hypotheses reached 88 % for the same number of evaluations."""

    particles: int = 128
    iterations: int = 10
    sigma_xy_m: float = 1.5
    sigma_z_m: float = 1.0
    sigma_yaw_deg: float = 1.0
    sigma_roll_pitch_deg: float | None = None  # None: half the prior's roll/pitch sigma (cascade)
    shrink: float = 0.65
    temperature: float = 0.3  # softmax temperature, in units of the population's score std
    update: str = "gaussian"  # "gaussian": weighted mean + covariance; "resample": systematic resampling
    lambda_semantic: float = 1.0  # lambda_1 of the paper
    lambda_depth: float = 1.0  # lambda_2: score = lambda_1 * C_s - lambda_2 * C_d (C_d is a cost)
    # Weight of the prior's roll/pitch penalty (refine.PriorTerm; 0 = none, as in the first design).
    # Calibration cities, 400 queries, R@2m,2deg: 0 -> 88 %, 0.001 / 0.003 / 0.005 -> 90 / 90 / 89 %,
    # 0.01 -> 86 %, 0.03 -> 72 %.
    prior_roll_pitch_weight: float = 0.003
    # Depth cost (kernels.refine_scores): "affine" = least-squares scale/shift, mean relative residual (the
    # paper's C_d); "robust" = relative least squares, each pixel's relative residual capped at depth_cap
    # (scoring.depth_cost and docs/localization.md give the measurements behind the choice).
    depth_cost: str = "robust"
    depth_cap: float = 0.3
    scale: int = 2  # render at scale x the coarse resolution (paper: twice)
    # The first iterations, while perturbations are still large, score at the coarse resolution (4x fewer
    # pixels); the rest at ``scale`` x. 0 = every iteration at the fine resolution (the paper's setting).
    low_res_iterations: int = 6
    # Polish: a second, narrow filter around the best particle at the fine resolution (0 iterations: none).
    polish_iterations: int = 4
    # 64 -> 48 (calibration cities, 400 queries, alone): 91.5 -> 92.0 % at 2 m / 2 deg, 2 gained, 0 lost.
    polish_particles: int = 48
    polish_sigma: tuple[float, float, float, float] = (0.5, 0.5, 0.15, 0.15)  # xy m, z m, roll/pitch, yaw deg
    # The polish's estimate: the mean of its best ``polish_estimate_top`` evaluations (0: its best one).
    # The score is noisy at the 0.1 m scale (the map is not the world), so its single best evaluation is
    # partly the luckiest noise. Calibration cities, realistic, 800 queries (seeds 0-3), R@2m,2deg:
    # best one 91.2 %, mean of the best 8 / 24 / 48 / 96: 92.0 / 92.5 / 92.6 / 92.6 % (48: 11 gained, 0 lost).
    polish_estimate_top: int = 48
    # Independent runs of the filter and its polish (other random draws); the one with the best final
    # score is kept. Calibration cities (realistic, 400 queries), R@2m,2deg: 1 run 91.5 %; 2 runs 90.5 %
    # (3 gained, 7 lost), 2 runs of 64 particles 89.0 % (5 gained, 15 lost): a higher score is not a
    # truer pose on the ridge's misses (docs/localization.md). Helps where the score peaks at the truth.
    restarts: int = 1
    # Roll/pitch/yaw perturbations turn the camera about a pivot on its optical axis at the median depth of
    # the scene (refine.pivot_jacobian: a step along the tilt-versus-shift ridge) in "both" filters, the
    # "polish" only, or about the camera centre ("none", before stop 25). Calibration cities, realistic,
    # R@2m,2deg / 3m,3deg (found): seeds 0-1 none 91.5 / 98.0 %, both 91.0 / 98.2 % (6 gained, 8 lost),
    # polish 91.5 / 98.0 % (0 / 0); seeds 2-3 none 92.8 / 99.0 %, both 94.5 / 99.8 % (14 / 7).
    pivot: str = "both"
    # The pose covariance (``covariance.py``): the score probed around the estimate with steps that move the
    # image by this many pixels at the fine resolution (73 evaluations); 0: no covariance. Calibration
    # cities (realistic, seed 0, 398 right poses, trained / medium masks), negative log-likelihood of the
    # errors per pose under the fitted covariance (lower is better; one constant covariance 3.94 / 4.47):
    # 0.4 px 3.06 / 3.28, 0.75 px 2.38 / 2.70, 1.25 px 2.67 / 3.14, 2 px 3.08 / 3.48, 3 px 3.58 / 4.00.
    covariance_probe_px: float = 0.75

    def __post_init__(self) -> None:
        if self.depth_cost not in DEPTH_COSTS:
            raise unknown_choice("depth cost", self.depth_cost, DEPTH_COSTS)
        if self.pivot not in PIVOTS:
            raise unknown_choice("pivot", self.pivot, PIVOTS)
        if int(self.restarts) < 1:
            raise ParameterError(f"refine.restarts must be >= 1, got {self.restarts}")


@dataclass(frozen=True)
class FocalCheckConfig:
    """The check of an accepted oblique pose's focal length (``focal_check.py``, stop 53): the view scored
    at the focal scales ``1 - step``, 1 and ``1 + step`` around the pose found (each moved along the
    optical axis, then a short polish of ``particles`` x ``iterations``); where the parabola through the
    three peaks more than ``margin`` from 1, a warning says the focal length may be off. Only views at
    least ``focal_check.MIN_OBLIQUE_DEG`` from nadir (seen from above, focal length and height are one
    unknown). ``enabled=False``: not run. A warning, never a refusal: with the focal length 5 % off
    most warned poses were right still (mostly 3-5 m off), and refusing them cost more recall than the
    precision it gained (docs/localization.md, "A focal length the image contradicts"). ``correct``: where
    it warns, the pose found again with the focal length times ``focal_check.correction_scale`` (the
    vertex, ``stretch`` times as far from 1) and kept when accepted and fitting the image better (stop 54,
    ``Localizer._correct_focal``)."""

    enabled: bool = True
    step: float = 0.03
    # Chosen on the calibration cities by a rule written first (docs/localization.md, "A focal length the
    # image contradicts"): the smallest of 0.005 / 0.0075 / 0.01 / 0.0125 / 0.015 whose false warnings
    # (the right focal length; generated seeds 0-2 and Fürth seed 0, 40 queries each, 159 accepted) are at
    # most 2.5 %: 23 / 12 / 8 / 7 / 4 of 159. With the focal length 5 % off it warned on 28 of their 42
    # accepted wrong poses (the other 14: nadir views, or vertices under the margin).
    margin: float = 0.015
    particles: int = 24
    iterations: int = 3
    # Where the check warns, the pose re-found with the focal length times ``1 + stretch (vertex - 1)``
    # (at most ``2 step`` from 1) and kept when it fits the image better and is accepted
    # (``Localizer._correct_focal``). Chosen by a rule written first (docs/localization.md, "A focal length
    # the image contradicts", the correction): generated and Fürth seeds 0-2, 40 queries each, pooled. With
    # the focal length 5 % long / short, precision 82.8 -> 93.7 / 78.2 -> 93.3 %, R@5m 82.5 -> 93.3 /
    # 77.9 -> 92.9 %, no right pose made wrong; with the right one 6 of 240 poses re-found, none made wrong,
    # R@2m 93.8 -> 93.3 %. ``stretch`` 2 gained as much at 5 m (more at 2 m) but with the right focal length
    # made one right pose wrong and lost 6 of 240 at 2 m. Off by default (the ``focal-correct`` preset):
    # held out (seed 6) the right focal length lost 1 of 80 at 2 m, past the criterion's 1 per 100, and
    # every pose it moved with the right focal length got worse (0.3-0.9 -> 1.4-2.8 m).
    correct: bool = False
    stretch: float = 1.0

    def __post_init__(self) -> None:
        for name in ("enabled", "correct"):
            if not isinstance(getattr(self, name), bool):
                raise ParameterError(f"focal_check.{name} must be True or False, got {getattr(self, name)!r}")
        for name, low, high in (("step", 0.005, 0.2), ("margin", 0.0, 0.2), ("stretch", 0.0, 5.0)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not low <= value <= high:
                raise ParameterError(f"focal_check.{name} must be a number in [{low}, {high}], got {value!r}")
        for name in ("particles", "iterations"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 1 <= value <= 1000:
                raise ParameterError(f"focal_check.{name} must be a whole number in [1, 1000], got {value!r}")


@dataclass(frozen=True)
class LocalizerConfig:
    """Everything that decides a localization's result: the search, the refinement, the acceptance, the map.

    Frozen, and built from a preset (``LocalizerConfig.preset``, ``PRESETS``); change a field with
    ``dataclasses.replace`` or the ``with_*`` helpers, which check values the same way. One typed object
    because a benchmark run records it in ``run.json`` (what decides the numbers) and resumes only with an
    equal one, and because the CLI, the benchmark and the library must localize with the same numbers. The
    fields are checked when made (``ParameterError`` naming the field), so a bad value fails at once rather
    than inside a search.
    """

    search: str = "cascade"  # "cascade" or "grid" (module docstring)
    cascade: CascadeConfig = field(default_factory=CascadeConfig)
    # The prior's uncertainty when the caller states none (``Localizer.localize(prior_uncertainty=)``).
    prior_uncertainty: PriorUncertainty = field(default_factory=PriorUncertainty)
    coarse: CoarseConfig = field(default_factory=CoarseConfig)  # search="grid" only
    refine: RefineConfig = field(default_factory=RefineConfig)
    # Optional first stage for large prior errors: a wide, sparse grid at a low resolution whose best cell
    # re-centres the regular coarse grid (LoD-Loc re-centres its 3 stages the same way).
    pre_coarse: CoarseConfig | None = None
    no_coarse: bool = False  # ablation: refine from the prior
    no_refine: bool = False  # ablation: coarse only
    no_depth: bool = False  # ablation: semantics only in the refinement
    # Acceptance of the final pose (else not_localized, "best score below threshold"):
    # without depth, C_s >= min_score; with depth, C_s >= min_semantic_with_depth and C_d <= max_depth_cost
    # (the depth fit separates true from false matches far better than the IoU alone when masks are poor).
    min_score: float = 0.5
    min_semantic_with_depth: float = 0.3
    max_depth_cost: float = 0.06
    # Building-vs-rest IoU at the final pose below this -> not_localized. Calibrated for a trained
    # segmentation head (Berlin: correct poses >= 0.80 at 78% mIoU masks; wrong look-alikes found from
    # priors 100+ m off <= 0.67). (The first design's gate; the default
    # preset's calibrated acceptance reads poor masks' evidence instead.)
    min_building_iou: float = 0.7
    min_building_fraction: float = 0.005  # query mask with fewer wall/roof pixels -> not_localized
    # "calibrated": accept when the estimated probability of being within 5 m / 5 deg
    # (``localization.confidence``) is at least ``min_confidence``; "thresholds": the hand-set gates above.
    acceptance: str = "calibrated"
    min_confidence: float = 0.5
    # A view spanning less of the scene than the calibration views (``confidence.close_view_warning``: flown
    # below about 40 m, or a narrow lens over tall buildings) is accepted only at this probability or
    # ``min_confidence``, whichever is higher: the fitted models overstate confidence there. Chosen on the
    # calibration cities flown 15-30 m up (seed 0, 100 queries each; the smallest of 0.7 / 0.8 / 0.9 / 0.95
    # whose accepted close views are 98 % within 5 m / 5 deg on each city): at 0.5 93.5 % (generated) and
    # 98.7 % (Fürth), at 0.8 97.2 / 100 %, at 0.9 98.5 / 100 %, refusing 5 and 6 of the 73 and 78 right
    # ones; the realistic calibration views (400) hold 3 close views, all kept (docs/localization.md).
    min_confidence_close_view: float = 0.9
    # Windows and doors of an LoD3 map: scored as classes of their own (True) or as wall (False). At the
    # search's resolutions (128 px across for the refinement, about 0.8 m a pixel at 75 m) an opening is a
    # pixel or two and the heads' window/door labels are mostly wrong, while the mean IoU gives each class
    # the weight of the whole roof. Generated city, LoD3 map, realistic, 200 queries (seeds 0 and 1),
    # R@2m,2deg / 3m,3deg / 5m,5deg: scored 62.0 / 83.5 / 96.5 %, as wall 89.5 / 97.5 / 99.5 %. Fixed
    # when a Localizer is built (its render scene's classes).
    score_openings: bool = False
    # Eaves added to the map's pitched roofs before the search renders it (``citymodel.eaves.with_eaves``;
    # 0 = the map as it is). LoD2 models cut roofs at their walls; real pitched roofs overhang them by
    # 0.3-1 m, which hides the walls' tops and moves every roof outline out: the largest single cause of
    # the calibration cities' misses (docs/localization.md, "The map's eaves"). 0.5 m, the lower middle
    # of that range, set before measuring. Calibration cities, realistic, R@2m,2deg (found): seeds 0-1
    # 91.0 -> 93.8 % (14 gained, 3 lost), seeds 2-3 94.5 -> 96.5 % (11 gained, 3 lost). Fixed when a
    # Localizer is built (its render scene); flat roofs (parapets) and LoD1 blocks get none.
    map_eaves_m: float = 0.5
    # Whether mostly flat roofs get those eaves too: "on", "off", or "auto" (per view): the map without
    # them is searched; where the found pose's view fits the map with them better (its semantic score
    # higher by more than ``flat_eaves_gate``) the refinement runs again on that map, and its pose is
    # taken when its semantic score beats the first's by more than ``flat_eaves_margin``. Flat roofs end
    # in a parapet at the wall line in the realistic scenario (and German LoD2 practice) and overhang in
    # some cities (slabs, bungalows). Calibration cities, seeds 0-1, 400 queries, R@2m,2deg (found):
    # parapets 93.75 % off, 93.75 % auto (21 of 400 refined twice, 13 taken), 89.5 % on; overhanging
    # 87.5 % off, 92.25 % auto (353 taken), 93.25 % on (docs/localization.md, "The map's eaves").
    # True / False read as "on" / "off".
    map_eaves_flat_roofs: str = "auto"
    # Both chosen on those queries. The gate: 0.001-0.003 gave the same recall within a query (0: 46
    # refined twice where roofs end in parapets, one lost at 3 m; 0.005 lost 3 at 2 m where they
    # overhang); 0.002 refines few views twice (the time). The margin 0.006: a per-view choice between two
    # whole runs (seed 0); 0 / 0.003 / 0.01 moved at most one query of 800.
    flat_eaves_gate: float = 0.002
    flat_eaves_margin: float = 0.006
    # A roll/pitch prior the image contradicts (``prior.roll_pitch_conflict``): where the found roll/pitch
    # departs from the prior's by more than this many sigmas of its stated uncertainty (0: never looked
    # at), the refinement runs again from the found pose with that sigma widened
    # (``prior.roll_pitch_wide_sigma``), and the pose whose image score (the same score without the
    # prior's term) is higher is kept; with ``roll_pitch_conflict_refuse`` a pose is refused instead when
    # the two lie farther apart than the acceptance tolerates. Either way a warning names the departure.
    # Chosen on the calibration cities (docs/localization.md, "A roll/pitch prior the image contradicts").
    roll_pitch_conflict_sigma: float = 2.0
    roll_pitch_conflict_refuse: bool = False
    # A departure of at most ``roll_pitch_sure_sigma`` sigmas is one the stated IMU itself gives now and
    # then (the norm of two Gaussian offsets passes 2 sigmas 13.5 % of the time, 3 sigmas 1.1 %): there the
    # second pose is taken only with an image-score gain above ``roll_pitch_unsure_gain``, beyond it with
    # any gain. Chosen on the calibration cities with the map's faults of the held-out runs (stop 54,
    # docs/localization.md, "A roll/pitch prior the image contradicts").
    roll_pitch_sure_sigma: float = 3.0
    roll_pitch_unsure_gain: float = 0.01
    # The focal-length check of an accepted oblique pose (``FocalCheckConfig``, ``focal_check.py``).
    focal_check: FocalCheckConfig = field(default_factory=FocalCheckConfig)
    seed: int = 0

    def __post_init__(self) -> None:
        for name, value, known in (
            ("search", self.search, SEARCHES),
            ("acceptance", self.acceptance, ACCEPTANCES),
        ):
            if value not in known:
                raise unknown_choice(name, value, known)
        if isinstance(self.map_eaves_flat_roofs, bool):  # the field's form before stop 46
            object.__setattr__(self, "map_eaves_flat_roofs", "on" if self.map_eaves_flat_roofs else "off")
        if self.map_eaves_flat_roofs not in FLAT_EAVES:
            raise unknown_choice("map_eaves_flat_roofs", self.map_eaves_flat_roofs, FLAT_EAVES)
        for name in ("flat_eaves_gate", "flat_eaves_margin"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not -1.0 <= value <= 1.0:
                raise ParameterError(f"{name} must be a score difference in [-1, 1], got {value!r}")
        k = self.roll_pitch_conflict_sigma
        if isinstance(k, bool) or not isinstance(k, (int, float)) or not 0.0 <= k <= 100.0:
            raise ParameterError(
                f"roll_pitch_conflict_sigma must be a number of sigmas in [0, 100], got {k!r}"
            )
        sure = self.roll_pitch_sure_sigma
        if isinstance(sure, bool) or not isinstance(sure, (int, float)) or not 0.0 <= sure <= 100.0:
            raise ParameterError(
                f"roll_pitch_sure_sigma must be a number of sigmas in [0, 100], got {sure!r}"
            )
        gain = self.roll_pitch_unsure_gain
        if isinstance(gain, bool) or not isinstance(gain, (int, float)) or not 0.0 <= gain <= 1.0:
            raise ParameterError(f"roll_pitch_unsure_gain must be a score difference in [0, 1], got {gain!r}")
        if not isinstance(self.roll_pitch_conflict_refuse, bool):
            raise ParameterError(
                f"roll_pitch_conflict_refuse must be True or False, got {self.roll_pitch_conflict_refuse!r}"
            )
        eaves = self.map_eaves_m
        if isinstance(eaves, bool) or not isinstance(eaves, (int, float)) or not 0.0 <= eaves <= 3.0:
            raise ParameterError(f"map_eaves_m must be a number of metres in [0, 3], got {eaves!r}")
        for name in ("min_confidence", "min_confidence_close_view"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 <= value <= 1.0:
                raise ParameterError(f"{name} must be a probability in [0, 1], got {value!r}")
        seed = self.seed
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ParameterError(f"seed must be a whole number >= 0, got {seed!r}")

    @classmethod
    def preset(cls, name: str) -> LocalizerConfig:
        """The preset ``name`` of ``PRESETS``, or several joined by commas (``"lookalikes,focal-correct"``:
        ``combine_presets``); ``ParameterError`` naming the presets otherwise."""
        names = preset_names(name)
        return PRESETS[names[0]] if len(names) == 1 else combine_presets(names)

    def with_ablation(self, method: str) -> LocalizerConfig:
        """The config of a method of ``ABLATION_FLAGS`` (``semcityloc``, ``no-coarse``, ...)."""
        if method not in ABLATION_FLAGS:
            raise unknown_choice("method", method, ABLATION_FLAGS)
        return replace(self, **ABLATION_FLAGS[method])

    def with_prior_sigma(self, text: str | None) -> LocalizerConfig:
        """This config with the prior uncertainty ``"xy=5,z=15,yaw=5,rp=1"`` (any subset, the rest from
        this config's; None: unchanged). ``ParameterError`` on a malformed text."""
        if text is None:
            return self
        return replace(self, prior_uncertainty=PriorUncertainty.parse(text, self.prior_uncertainty))

    def with_map_eaves(
        self, eaves_m: float | None = None, flat_roofs: str | bool | None = None
    ) -> LocalizerConfig:
        """This config with the map's eaves ``eaves_m`` and their ``flat_roofs`` mode (``FLAT_EAVES``; None:
        unchanged; the ``--map-eaves`` / ``--map-eaves-flat`` options; checked like any field)."""
        changes: dict = {}
        if eaves_m is not None:
            changes["map_eaves_m"] = eaves_m
        if flat_roofs is not None:
            changes["map_eaves_flat_roofs"] = flat_roofs
        return replace(self, **changes) if changes else self

    def as_dict(self) -> dict:
        """The config as nested plain dicts (``dataclasses.asdict``): what ``run.json`` records and
        compares.
        """
        return asdict(self)


# The localizer's own methods: the full pipeline and its ablations (``with_ablation``), as config flags.
ABLATION_FLAGS: dict[str, dict[str, bool]] = {
    "semcityloc": {},
    "no-coarse": {"no_coarse": True},
    "no-refine": {"no_refine": True},
    "no-depth": {"no_depth": True},
}

# The first design (issue 4), kept to measure against: a fixed +-16 m (xy) / +-8 m (z) / +-9 deg grid,
# roll and pitch held at the prior's and moved by 0.3 deg in the refinement, hand-set acceptance.
LEGACY = LocalizerConfig(
    search="grid",
    refine=RefineConfig(
        sigma_roll_pitch_deg=0.3,
        prior_roll_pitch_weight=0.0,
        depth_cost="affine",
        polish_iterations=0,
        pivot="none",
        covariance_probe_px=0.0,
    ),
    acceptance="thresholds",
    score_openings=True,
    map_eaves_m=0.0,
    focal_check=FocalCheckConfig(enabled=False),
)

PRESETS: dict[str, LocalizerConfig] = {
    # The cascade over the prior's stated uncertainty (default: DJI GNSS + gimbal IMU, +-15 m xy,
    # +-30 m z, +-9 deg yaw, roll/pitch sampled and refined), calibrated acceptance.
    "default": LocalizerConfig(),
    # The first design, unchanged (docs/localization.md "The first design"): for comparisons.
    "legacy": LEGACY,
    # The first design's variants for large prior errors (kept for the runs documented with them).
    "legacy-wide-z": replace(LEGACY, coarse=CoarseConfig(range_z_m=60.0, n_z=13)),
    # The default scoring an LoD3 map's windows and doors as classes of their own (the default before
    # stop 22): the LoD table's "openings scored" row is this preset.
    "openings": replace(LocalizerConfig(), score_openings=True),
    # The default searching the map as it is: for models whose roofs already overhang their walls
    # (photogrammetric or hand-made LoD2/LoD3), where the default's 0.5 m eaves would be counted twice.
    "no-eaves": replace(LocalizerConfig(), map_eaves_m=0.0),
    # The default refusing a pose that a look-alike more than 5 m away fits about as well (``lookalike.py``):
    # for estates of identical houses, where the default accepts the view one house along.
    "lookalikes": LocalizerConfig(cascade=CascadeConfig(lookalike=LookalikeConfig(enabled=True))),
    # The default finding a pose again with the focal length its view fits, where the focal check fires
    # (``FocalCheckConfig.correct``): for photos whose focal length is known to a few percent only (a 35 mm-
    # equivalent EXIF value, no calibration). With the right focal length it costs the few views it fires on.
    "focal-correct": LocalizerConfig(focal_check=FocalCheckConfig(correct=True)),
    # Small and quick, for tests and the demo's smoke runs.
    "fast": LocalizerConfig(
        cascade=CascadeConfig(sweep=SweepConfig(max_centres=600, keep=4), local=LocalConfig(keep=2)),
        refine=RefineConfig(particles=64, iterations=6, low_res_iterations=3),
    ),
}


PRESET_JOIN = ","  # presets combined: their names joined by it, "lookalikes,focal-correct"


def preset_names(name: str) -> tuple[str, ...]:
    """The presets ``name`` (one of ``PRESETS`` or several joined by ``PRESET_JOIN``) combines, each once
    and in ``PRESETS``' order (the combination's one spelling, ``preset_name``), ``default`` left out of a
    combination (it changes nothing); ``ParameterError`` naming the presets for an unknown one."""
    given = [n.strip() for n in str(name).split(PRESET_JOIN)]
    unknown = [n for n in given if n not in PRESETS]
    if unknown:
        raise unknown_choice("localizer preset", unknown if len(unknown) > 1 else unknown[0], PRESETS)
    names = tuple(n for n in PRESETS if n in given and (n != "default" or set(given) == {"default"}))
    return names


def preset_name(name: str) -> str:
    """The one spelling of a preset or a combination of presets (``preset_names``), as a run records it:
    ``"focal-correct, lookalikes"`` -> ``"lookalikes,focal-correct"``."""
    return PRESET_JOIN.join(preset_names(name))


def _changes(config, base, at: tuple[str, ...] = ()) -> dict[tuple[str, ...], object]:
    """The settings (dotted paths into the nested configs) where ``config`` differs from ``base``."""
    out: dict[tuple[str, ...], object] = {}
    for f in fields(config):
        value, was = getattr(config, f.name), getattr(base, f.name)
        if is_dataclass(value) and type(value) is type(was):
            out.update(_changes(value, was, (*at, f.name)))
        elif value != was:
            out[(*at, f.name)] = value
    return out


def _changed(config, changes: dict[tuple[str, ...], object]):
    """``config`` with ``changes`` (``_changes``' form) made, each nested config replaced as a whole."""
    own = {path[0]: value for path, value in changes.items() if len(path) == 1}
    nested: dict[str, dict] = {}
    for path, value in changes.items():
        if len(path) > 1:
            nested.setdefault(path[0], {})[path[1:]] = value
    own.update({name: _changed(getattr(config, name), sub) for name, sub in nested.items()})
    return replace(config, **own)


def _switched_off(config: LocalizerConfig) -> dict[tuple[str, ...], str]:
    """The nested configs ``config`` leaves unused, each with the setting that does: one whose ``enabled``
    is False, and the cascade's under ``search="grid"``."""
    out = {("cascade",): 'search="grid"'} if config.search == "grid" else {}
    stack: list[tuple[tuple[str, ...], object]] = [((), config)]
    while stack:
        at, node = stack.pop()
        for f in fields(node):
            value = getattr(node, f.name)
            if is_dataclass(value):
                if getattr(value, "enabled", True) is False:
                    out[(*at, f.name)] = ".".join((*at, f.name, "enabled")) + "=False"
                stack.append(((*at, f.name), value))
    return out


def combine_presets(names: tuple[str, ...] | list[str]) -> LocalizerConfig:
    """The default with the settings each preset of ``names`` changes from it, all of them. Why this rule:
    every preset but ``legacy`` is the default with a few settings changed, so two of them that change
    different settings mean both (``lookalikes`` + ``focal-correct``: the look-alike test and the focal
    correction). ``ParameterError`` in one line when two set one setting to different values, or one
    switches off what another sets (``legacy`` turns the focal check off, ``focal-correct`` sets its
    correction): one of the two would be dropped silently."""
    base = LocalizerConfig()
    changes: dict[tuple[str, ...], tuple[str, object]] = {}
    for name in names:
        for path, value in _changes(PRESETS[name], base).items():
            other, was = changes.setdefault(path, (name, value))
            if was != value:
                raise ParameterError(
                    f"presets {other} and {name} set {'.'.join(path)} to different values ({was!r}, "
                    f"{value!r}): they cannot be combined; choose one of them"
                )
    config = _changed(base, {path: value for path, (_, value) in changes.items()})
    switched_off = _switched_off(config)
    for path, (name, _) in changes.items():
        for off, why in switched_off.items():
            if path[: len(off)] == off and len(path) > len(off) and off not in _switched_off(PRESETS[name]):
                culprit = next(n for n in names if off in _switched_off(PRESETS[n]))
                raise ParameterError(
                    f"presets {culprit} and {name} cannot be combined: {culprit} sets {why}, which leaves "
                    f"{'.'.join(path)} of {name} unused; choose one of them"
                )
    return config


def config_or_preset(config: LocalizerConfig | str | None) -> LocalizerConfig:
    """A ``LocalizerConfig`` from a config, a preset name (``PRESETS``, or several joined by commas) or
    None (the default)."""
    if config is None:
        return LocalizerConfig()
    if isinstance(config, str):
        return LocalizerConfig.preset(config)
    if not isinstance(config, LocalizerConfig):
        raise ParameterError(
            f"config must be a LocalizerConfig or a preset name, got {type(config).__name__}"
        )
    return config
