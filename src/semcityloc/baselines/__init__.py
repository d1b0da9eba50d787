"""Baselines: LoD-Loc-style wireframe alignment and silhouette IoU."""
