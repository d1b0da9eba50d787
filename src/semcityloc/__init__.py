"""semcityloc: 6DoF UAV localization against semantic 3D city models.

The pipeline reads a city model (``semcityloc.citymodel``), renders semantic masks and depth from
hypothesised poses (``semcityloc.render``) and aligns them with the query's segmentation and depth.
"""

from semcityloc.classes import SemanticClass
from semcityloc.errors import SemCityLocError

__all__ = ["SemCityLocError", "SemanticClass", "__version__"]
__version__ = "0.1.0"
