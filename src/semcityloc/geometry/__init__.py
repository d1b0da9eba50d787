"""Cameras and poses: ``Camera`` (pinhole intrinsics, OpenCV axes), ``Pose`` (cam_from_world, float64) and
the prior's ``PriorUncertainty``; the conventions they follow are docs/conventions.md."""

from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose
from semcityloc.geometry.uncertainty import PriorUncertainty

__all__ = ["Camera", "Pose", "PriorUncertainty"]
