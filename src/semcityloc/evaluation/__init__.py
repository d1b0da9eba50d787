"""Evaluation of localization results: pose-error metrics (recall at thresholds, mean/median errors)."""
