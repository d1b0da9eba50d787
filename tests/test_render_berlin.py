"""The numba rasteriser against the Embree ray caster on the real Berlin LoD2 district."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose
from semcityloc.render import Renderer
from semcityloc.render.embree_ref import embree_available

pytestmark = [
    pytest.mark.skipif(
        importlib.util.find_spec("semcityloc.citymodel.citygml") is None,
        reason="the CityGML reader semcityloc.citymodel.citygml is not available",
    ),
    pytest.mark.skipif(not embree_available(), reason="embreex (semcityloc[reference]) not installed"),
]


@pytest.fixture
def berlin(shared):
    from semcityloc.citymodel.citygml import read_citygml

    return read_citygml(shared("berlin_lod2_citygml2/3910_5817.gml"))


@pytest.mark.parametrize("pitch", [(0.0, 5.0), (30.0, 60.0)], ids=["nadir", "oblique"])
def test_numba_agrees_with_embree_on_berlin(berlin, pitch):
    numba_r = Renderer(berlin, engine="numba")
    embree_r = Renderer(berlin, engine="embree")
    rng = np.random.default_rng(42 + int(pitch[0]))
    lo, hi = berlin.bounds_local
    n = 60
    ground_z = lo[2]
    xyz = np.column_stack(
        [rng.uniform(lo[0], hi[0], n), rng.uniform(lo[1], hi[1], n), hi[2] + rng.uniform(40, 150, n)]
    )
    assert (xyz[:, 2] - ground_z > 40).all()
    poses = Pose.from_xyz_rpy(xyz, rng.normal(0, 2, n), rng.uniform(*pitch, n), rng.uniform(-180, 180, n))
    for cam in (Camera.from_fov(64, 48, 60.0), Camera.from_fov(128, 96, 60.0)):
        a = numba_r.render(cam, poses, depth=True, face_ids=True)
        b = embree_r.render(cam, poses, depth=True, face_ids=True)
        assert (a.labels == b.labels).mean() >= 0.995
        both = np.isfinite(a.depth) & np.isfinite(b.depth)
        same_face = both & (a.face_ids == b.face_ids)
        assert same_face.sum() > 0.5 * both.sum()
        rel = np.abs(a.depth[same_face] - b.depth[same_face]) / b.depth[same_face]
        assert rel.max() <= 1e-3
        # Where they hit different triangles (coplanar or touching surfaces) the depth still agrees.
        rel_all = np.abs(a.depth[both] - b.depth[both]) / b.depth[both]
        assert np.quantile(rel_all, 0.995) <= 1e-3
