"""Localization: the search over the prior's uncertainty, the particle-filter refinement and the calibrated
acceptance (docs/localization.md). ``Localizer(model).localize(camera, prior_local, semantic, depth)`` or
the one-shot ``localize(...)``; poses in and out in the model's local frame."""

from semcityloc.localization.config import LocalizerConfig
from semcityloc.localization.localize import Localizer, localize
from semcityloc.localization.result import LocalizationResult

__all__ = ["LocalizationResult", "Localizer", "LocalizerConfig", "localize"]
