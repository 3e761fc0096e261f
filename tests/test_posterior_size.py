"""The run folder of a large contact set stays bounded: the log-likelihood and posterior-predictive groups hold at
most OBSERVATION_VALUES values (issue 24: 50,000 contacts took half a minute and 8.7 GB after the budget)."""

import arviz as az
import numpy as np

from bayestouch.inference import contact as cm
from bayestouch.inference import posterior as po
from bayestouch.inference.run import contact_model
from bayestouch.inference.sampler import Chain


def _chain(rng, walkers=32, steps=40):
    theta = np.r_[0.0, 0.0, 0.0, np.log([0.02, 0.02, 0.02]), 0.5, 0.3, 0.2, np.log(2.0), np.log(3e-4)]
    kept = theta + 1e-3 * rng.standard_normal((steps, walkers, 11))
    return Chain(kept, np.zeros((steps, walkers)), steps, 0, 5.0, 0.3, False, 1.0)


def _points(rng, m):
    u = rng.standard_normal((m, 3))
    return 0.02 * u / np.linalg.norm(u, axis=1, keepdims=True) + 3e-4 * rng.standard_normal((m, 3))


def test_large_data_get_fewer_predictive_draws_and_the_same_log_likelihoods(tmp_path, rng):
    ch = _chain(rng)
    pri = cm.load_priors()
    big = _points(rng, 20_000)
    s = po.write_posterior(tmp_path / "big", ch, contact_model(big, pri, np.inf), seed=0, t0=0.0)
    idata = az.from_netcdf(tmp_path / "big" / "posterior.nc")
    ll = idata.log_likelihood["points"]
    assert ll.sizes["chain"] * ll.sizes["draw"] * ll.sizes["point"] <= po.OBSERVATION_VALUES
    pp = idata.posterior_predictive["points"]
    assert pp.sizes["chain"] * pp.sizes["draw"] * pp.sizes["point"] <= po.OBSERVATION_VALUES
    assert s["diagnostics"]["n_samples"] == 32 * 40
    # the batched log-likelihood equals one call's (the batches only bound memory)
    draws = ch.kept[0]
    one = cm.pointwise_log_likelihood(draws, big)
    batched = po._in_batches(lambda d: {"points": cm.pointwise_log_likelihood(d, big)}, draws, len(big), 100_000)
    np.testing.assert_allclose(batched["points"], one, rtol=1e-9, atol=1e-12)  # XLA rounding by batch size
    # negative control: a small set keeps the usual PREDICTIVE_DRAWS
    small = _points(rng, 200)
    po.write_posterior(tmp_path / "small", ch, contact_model(small, pri, np.inf), seed=0, t0=0.0)
    ll_small = az.from_netcdf(tmp_path / "small" / "posterior.nc").log_likelihood["points"]
    assert ll_small.sizes["draw"] == po.PREDICTIVE_DRAWS // 32 and ll.sizes["draw"] < ll_small.sizes["draw"]
