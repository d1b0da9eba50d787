"""How far the search may move the camera from the prior, and what a best hypothesis left at that reach asks
of the user.

The cascade's volume (``cascade.search_volume``) grows where its best cell lies on an edge, by
``SweepConfig.extension`` of its half-width at most ``max_extensions`` times: ``reached_half`` is the volume
at its largest. ``search_half_xy`` is either search's horizontal reach (the ``legacy`` grid's is its range);
the localizer looks for buildings that far around the prior's view before it searches, and a tile store
loads the tiles that far around a photo's (``tiled.reach_radius``). A best hypothesis still on an edge at the
largest extent is refused, not taken (``REASON_AT_EDGE``): its warning (``edge_warning``) names the
``--prior-sigma`` whose volume starts at twice the bound reached (``edge_sigma``), and a refused pose with
a better view beyond the reach names one the same way (``Localizer._look_beyond``).
"""

from __future__ import annotations

import math

from semcityloc.geometry.pose import Pose
from semcityloc.geometry.uncertainty import PriorUncertainty
from semcityloc.localization.cascade import SearchVolume, search_volume
from semcityloc.localization.config import CascadeConfig, LocalizerConfig


def reached_half(volume: SearchVolume, config: CascadeConfig) -> dict[str, float]:
    """The half-widths per ``--prior-sigma`` key (``xy``, ``z`` m; ``yaw`` deg) of ``volume`` grown by its
    largest extension: how far from the prior the cascade may search."""
    grown = 1.0 + config.sweep.max_extensions * config.sweep.extension
    return {"xy": grown * volume.half_xy_m, "z": grown * volume.half_z_m, "yaw": grown * volume.half_yaw_deg}


def search_half_xy(prior_local: Pose, cfg: LocalizerConfig, unc: PriorUncertainty) -> float:
    """How far (m, in x and in y) the search may move the camera from the prior: the grid's range, or the
    cascade's volume grown by its largest extension."""
    if cfg.search == "grid":
        pre = cfg.pre_coarse.range_xy_m if cfg.pre_coarse is not None else 0.0
        return (cfg.coarse.range_xy_m + pre) / 2
    return reached_half(search_volume(prior_local.to_xyz_rpy(), unc, cfg.cascade), cfg.cascade)["xy"]


def edge_sigma(edges: list[str], volume: SearchVolume, config: CascadeConfig) -> dict[str, int]:
    """The prior sigma per ``--prior-sigma`` key of the ``edges`` (``["z-"]``) the best hypothesis stayed on
    at the volume's largest extension: the one whose volume starts at twice the bound that was reached
    (``n_sigma`` sigmas = 2 x ``reached_half``)."""
    half = reached_half(volume, config)
    axes = dict.fromkeys("xy" if e.rstrip("+-") in ("x", "y") else e.rstrip("+-") for e in edges)
    return {a: math.ceil(2.0 * half[a] / config.n_sigma) for a in axes}


def edge_warning(edges: list[str], volume: SearchVolume, config: CascadeConfig) -> str:
    """What a user should do when the best hypothesis stayed on the search volume's ``edges``: state the
    ``edge_sigma``, or correct the prior."""
    half = reached_half(volume, config)
    sigma = edge_sigma(edges, volume, config)
    reached = ", ".join(f"{a} +-{half[a]:.0f} {'deg' if a == 'yaw' else 'm'}" for a in sigma)
    return (
        f"the best hypothesis stayed on the search volume's {' '.join(edges)} edge at its largest extent "
        f"({reached} around the prior): the prior is further off than its stated uncertainty; run again "
        f"with --prior-sigma {','.join(f'{a}={v}' for a, v in sigma.items())} or correct the prior"
    )
