"""benchmarks/bench_objects.py: the non-superquadric truths and their touch sets are what its docstring says."""

import numpy as np
import pytest

from bayestouch.geometry.compare import surface_distance
from bayestouch.geometry.winding import mesh_inside

bo = pytest.importorskip("benchmarks.bench_objects")
pytest.importorskip("manifold3d")


@pytest.mark.parametrize("i, kind", list(enumerate(bo.KINDS)))
def test_object_sets_touch_the_true_mesh(i, kind):
    d = bo.make_object_set(100 + i, kind)
    mesh = (d.vertices, d.faces)
    assert d.kind == kind and d.volume > 0 and 0.005 < d.size < 0.06
    m = len(d.points)
    assert bo.POINTS_RANGE[0] <= m <= bo.POINTS_RANGE[1] and d.stroke.max() + 1 >= bo.STROKES_RANGE[0]
    clean = d.outlier_sign == 0
    dist = surface_distance(mesh, d.points)
    # undisplaced contacts lie on the surface to the 0.3 mm noise (|d| of a 3-D Gaussian step ≤ 5 sd)
    assert np.all(dist[clean] < 5 * bo.NOISE_M) and np.median(dist[clean]) < 2 * bo.NOISE_M
    inside = mesh_inside(*mesh, d.points)
    assert np.all(inside[d.outlier_sign < 0]) and not np.any(inside[d.outlier_sign > 0])
    assert len(d.free_space) and not np.any(mesh_inside(*mesh, d.free_space))
    again = bo.make_object_set(100 + i, kind)
    np.testing.assert_array_equal(again.points, d.points)  # one seed, one set


def test_unknown_kind_is_refused():
    with pytest.raises(ValueError, match="unknown kind"):
        bo.object_mesh("teapot", np.random.default_rng(0))
