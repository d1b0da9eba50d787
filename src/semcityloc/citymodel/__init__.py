"""City model in: CityGML 1.0/2.0/3.0, CityJSON and OBJ read into one semantic ``CityModel`` mesh."""

from semcityloc.citymodel.io import load_city_model
from semcityloc.citymodel.model import CityModel, ParseStats
from semcityloc.citymodel.pose_crs import read_pose_world

__all__ = ["CityModel", "ParseStats", "load_city_model", "read_pose_world"]
