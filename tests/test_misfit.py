"""The misfit check (bayestouch.inference.misfit): the true shape's residuals are noise and are never flagged; a
shape off by millimetres, or a wrong exponent, is flagged; a fit in the wrong mode says so in summary.json."""

import numpy as np

from bayestouch.geometry import nellipsoid as ne
from bayestouch.geometry.mesh import sample_surface
from bayestouch.inference import misfit as mf


def contacts(seed: int, count: int = 80, noise: float = 3e-4, n: float = 3.0):
    """Contacts (count, 3) m on one side (z > −5 mm) of an n-ellipsoid with semi-axes 30/20/15 mm, noise sd
    ``noise`` m along each coordinate, and the true θ (10,)."""
    s = ne.NEllipsoid(np.zeros(3), np.array([0.03, 0.02, 0.015]), np.array([0.3, 0.5, 0.2]), float(n))
    rng = np.random.default_rng(seed)
    p = np.asarray(sample_surface(s, 4 * count, seed=rng))
    p = p[p[:, 2] > -0.005][:count]
    theta = np.concatenate([np.zeros(3), np.log(s.axes), s.angles, [np.log(n)]])
    return p + rng.normal(0, noise, p.shape), theta


def test_neighbour_pairs_join_each_point_to_its_nearest():
    p = np.array([[0, 0, 0], [1, 0, 0], [10, 0, 0], [10.5, 0, 0], [0, 0, 0]], float)
    pairs = {tuple(x) for x in mf.neighbour_pairs(p)}
    assert pairs == {(0, 4), (1, 4), (2, 3)} or pairs == {(0, 4), (0, 1), (2, 3)}
    assert mf.neighbour_pairs(p[:1]).shape == (0, 2)


def test_the_true_shape_is_never_a_misfit():
    """Negative control: at the truth the residuals are independent noise; over 30 sets ρ averages ~0 (within 4
    standard errors) and no set is flagged."""
    rhos = []
    for seed in range(30):
        p, theta = contacts(seed)
        r = mf.residual_structure(p, theta[None], seed=seed)
        assert not r["misfit"]
        rhos.append(r["rho"])
    assert abs(np.mean(rhos)) < 4 * np.std(rhos) / np.sqrt(len(rhos)) + 0.02


def test_a_wrong_shape_is_flagged():
    """n 3 fitted as 2 leaves smooth residuals: flagged in each of 5 sets (ρ 0.70–0.75, z 5.1–6.1 measured).
    Semi-axes 5 % too long shift every contact by 0.75–1.5 mm, nearly a constant that ranks barely see: ρ 0.07–0.43,
    z 0.5–3.4, flagged in 3 of 5."""
    longer_flagged = 0
    for seed in range(5):
        p, theta = contacts(seed)
        rounder = theta.copy()
        rounder[9] = np.log(2.0)
        r = mf.residual_structure(p, rounder[None], seed=seed)
        assert r["misfit"] and r["rho"] > 0.5 and r["z"] > 4
        longer = theta.copy()
        longer[3:6] += np.log(1.05)
        longer_flagged += mf.residual_structure(p, longer[None], seed=seed)["misfit"]
    assert longer_flagged >= 3


def test_too_few_contacts_give_no_verdict():
    p, theta = contacts(0, count=12)
    r = mf.residual_structure(p, theta[None])
    assert r["misfit"] is False and (r["rho"] is None or r["pairs"] >= mf.MIN_PAIRS)
