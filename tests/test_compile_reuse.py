"""Data sets of different lengths share compiled programs: the pointwise log-likelihood, the misfit check's
residuals and normals and the draws' volumes (like the posterior predictive's feet) pad their inputs to size
buckets, so a fit of a new data set (or a chain of a new length) reuses what an earlier one compiled, in one process
and through the command line's persistent compilation cache. Each check counts the jitted function's compiled
programs and compares the padded results with the unpadded computation."""

import numpy as np

from bayestouch.geometry import nellipsoid as ne
from bayestouch.inference import contact as cm
from bayestouch.inference import misfit
from bayestouch.inference.posterior import _volumes, draw_volumes

THETA = np.array([0.001, -0.002, 0.0, np.log(0.03), np.log(0.02), np.log(0.015), 0.4, 0.3, -0.5, np.log(2.5)])


def _surface_points(m: int, seed: int = 0) -> np.ndarray:
    """M noisy points near the surface of THETA (3-D noise 0.3 mm)."""
    from bayestouch.inference.sbc import simulate_points

    th = np.concatenate([THETA, [np.log(3e-4)]])
    return simulate_points(th, m, np.random.default_rng(seed))


def test_pointwise_log_likelihood_of_two_lengths_in_one_bucket_compiles_once_and_sums_to_the_log_likelihood():
    lengths = (83, 87)
    assert len({cm.padded_size(m) for m in lengths}) == 1
    thetas = np.concatenate([THETA, [np.log(3e-4)]])[None].repeat(4, axis=0)
    thetas[:, 3] += np.linspace(-0.05, 0.05, 4)
    cm._log_lik_terms_jit.clear_cache()
    sizes = []
    for m in lengths:
        pts = _surface_points(m, seed=m)
        terms = cm.pointwise_log_likelihood(thetas, pts, np.inf)
        assert terms.shape == (4, m)
        # the padding columns are cut off: the terms sum to the batched log-likelihood (prior added back)
        logp, bounds = cm.make_log_prob(pts, nu=np.inf)
        lp, ll, _, _ = logp.parts(thetas)
        np.testing.assert_allclose(terms.sum(axis=1), ll, rtol=1e-10, atol=1e-8)
        sizes.append(cm._log_lik_terms_jit._cache_size())
    assert sizes == [1, 1]


def test_misfit_residuals_reuse_one_program_and_equal_the_plain_residuals():
    th = np.concatenate([THETA, [np.log(3e-4)]])
    misfit._residuals_normals_jit.clear_cache()
    sizes = []
    for m in (70, 100):  # both pad to 128
        pts = _surface_points(m, seed=m)
        d, nrm = misfit._residuals_and_normals(th, pts)
        np.testing.assert_allclose(d, np.asarray(cm.residuals(th[:10], pts)), rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(nrm, np.asarray(ne.normals(cm.shape_of(th[:10]), pts)), rtol=1e-12, atol=1e-15)
        sizes.append(misfit._residuals_normals_jit._cache_size())
    assert sizes == [1, 1]
    # negative control: a length in another power-of-two bucket compiles a new program
    misfit._residuals_and_normals(th, _surface_points(200))
    assert misfit._residuals_normals_jit._cache_size() == 2


def test_draw_volumes_of_chains_of_different_lengths_reuse_programs():
    rng = np.random.default_rng(1)
    _volumes.clear_cache()
    vec = np.concatenate([THETA[:3], np.exp(THETA[3:6]), THETA[6:9], [np.exp(THETA[9])]])
    for n in (20533, 20534):  # one block of 16384 and a remainder padded to 8192, for both
        v = vec[None].repeat(n, axis=0)
        v[:, 3:6] *= rng.uniform(0.8, 1.2, size=(n, 3))
        vol = draw_volumes(v)
        assert vol.shape == (n,)
        exact = np.array([float(ne.volume(ne.from_vector(r))) for r in v[:: n // 7]])
        np.testing.assert_allclose(vol[:: n // 7], exact, rtol=1e-12)
        assert _volumes._cache_size() == 2  # the block of 16384 and the remainder's 8192, for both lengths
