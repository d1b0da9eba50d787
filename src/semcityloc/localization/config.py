"""Named configuration presets of the localizer (hloc-style: a dict of named, documented presets).

Every number the search uses lives here; ``LocalizerConfig.preset(name)`` returns a copy to tweak.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace

from semcityloc.errors import unknown_choice


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
        return self.n_xy * self.n_xy * self.n_z * self.n_yaw


@dataclass(frozen=True)
class RefineConfig:
    """Particle filter around the coarse pose. Perturbation scales shrink by ``shrink`` per iteration."""

    particles: int = 128
    iterations: int = 10
    sigma_xy_m: float = 1.5
    sigma_z_m: float = 1.0
    sigma_yaw_deg: float = 1.0
    sigma_roll_pitch_deg: float = 0.3
    shrink: float = 0.65
    temperature: float = 0.3  # softmax temperature, in units of the population's score std
    update: str = "gaussian"  # "gaussian": weighted mean + covariance; "resample": systematic resampling
    lambda_semantic: float = 1.0  # lambda_1 of the paper
    lambda_depth: float = 1.0  # lambda_2: score = lambda_1 * C_s - lambda_2 * C_d (C_d is a cost)
    scale: int = 2  # render at scale x the coarse resolution (paper: twice)
    # The first iterations, while perturbations are still large, score at the coarse resolution (4x fewer
    # pixels); the rest at ``scale`` x. 0 = every iteration at the fine resolution (the paper's setting).
    low_res_iterations: int = 6


@dataclass(frozen=True)
class LocalizerConfig:
    coarse: CoarseConfig = field(default_factory=CoarseConfig)
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
    # priors 100+ m off <= 0.67). Poor (zero-shot) masks need the "poor-masks" preset.
    min_building_iou: float = 0.7
    min_building_fraction: float = 0.005  # query mask with fewer wall/roof pixels -> not_localized
    seed: int = 0

    @classmethod
    def preset(cls, name: str) -> LocalizerConfig:
        """The preset ``name`` of ``PRESETS`` (``ParameterError`` naming the presets otherwise)."""
        if name not in PRESETS:
            raise unknown_choice("localizer preset", name, PRESETS)
        return PRESETS[name]

    def with_ablation(self, method: str) -> LocalizerConfig:
        """The config of a method of ``ABLATION_FLAGS`` (``semcityloc``, ``no-coarse``, ...)."""
        if method not in ABLATION_FLAGS:
            raise unknown_choice("method", method, ABLATION_FLAGS)
        return replace(self, **ABLATION_FLAGS[method])

    def as_dict(self) -> dict:
        return asdict(self)


# The localizer's own methods: the full pipeline and its ablations (``with_ablation``), as config flags.
ABLATION_FLAGS: dict[str, dict[str, bool]] = {
    "semcityloc": {},
    "no-coarse": {"no_coarse": True},
    "no-refine": {"no_refine": True},
    "no-depth": {"no_depth": True},
}

PRESETS: dict[str, LocalizerConfig] = {
    # Covers the benchmark's prior noise (translation up to 15 m, yaw up to 8 deg): 13*13*7*13 = 15,379.
    "default": LocalizerConfig(),
    # Wider translation search for priors with extra per-axis perturbation.
    "wide": LocalizerConfig(coarse=CoarseConfig(range_xy_m=64.0, n_xy=21, range_z_m=24.0, n_z=9)),
    # Priors whose height is far off (e.g. barometric/GNSS altitude; the real UAVD4L-LoD prior is 20.7 m
    # high): LoD-Loc's +-30 m height range in 5 m steps.
    "wide-z": LocalizerConfig(coarse=CoarseConfig(range_z_m=60.0, n_z=13)),
    # Priors tens of metres off on every axis (the paper's prior-sensitivity bins up to 40-50 m): a
    # pre-stage over +-65 m in x, y, z (5-6 m steps, 32x24 masks, 23*23*27*7 = 99,981 hypotheses) in front
    # of the default grid.
    "extended": LocalizerConfig(
        pre_coarse=CoarseConfig(
            range_xy_m=130.0,
            n_xy=23,
            range_z_m=130.0,
            n_z=27,
            range_yaw_deg=18.0,
            n_yaw=7,
            width=32,
            height=24,
        )
    ),
    # Zero-shot-quality masks (mIoU ~35%): correct poses then overlap 0.29-0.55 in building IoU, so the
    # floor is low; wrong look-alikes pass it too when the prior is far off (see docs/localization.md).
    "poor-masks": LocalizerConfig(min_building_iou=0.25),
    # Small and quick, for tests and the demo's smoke runs.
    "fast": LocalizerConfig(
        coarse=CoarseConfig(range_xy_m=24.0, n_xy=9, n_z=5, n_yaw=9, width=48, height=36),
        refine=RefineConfig(particles=64, iterations=6, low_res_iterations=3),
    ),
}
