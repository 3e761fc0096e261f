"""Simulation-based calibration (SBC; Talts, Betancourt, Simpson, Vehtari & Gelman 2018) of the contact-level
model: is its posterior, as sampled by the project's emcee engine, calibrated? Simulated data sets of M contact
points (M, 3) m from the generating prior ``GEN_PRIOR`` (θ (11,)), the rank of each symmetry-invariant quantity's
truth (centre m, sorted semi-axes m, n, σ m, volume m³) among L posterior draws, rank histograms with chi-square
p-values and 90 % coverage. The method, the prior and the measured results: ``docs/sbc.md``.
"""

from __future__ import annotations

import logging
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import NamedTuple

import emcee
import numpy as np
from scipy.special import gammaln
from scipy.stats import binom, chi2

from bayestouch.backend import jax, jnp
from bayestouch.errors import BadInput
from bayestouch.geometry import nellipsoid as ne
from bayestouch.geometry.mesh import cube_sphere, sample_surface
from bayestouch.inference import contact as cm
from bayestouch.inference.sampler import sample

__all__ = [
    "GEN_PRIOR",
    "QUANTITIES",
    "SBCResult",
    "de_moves",
    "plot_ranks",
    "prior_box",
    "draw_prior",
    "simulate_points",
    "invariants",
    "make_sbc_log_prob",
    "posterior_draws",
    "ranks_of",
    "coverage_of",
    "uniformity_pvalues",
    "sbc",
]

_log = logging.getLogger(__name__)

#: generating (= inference) prior, uniform in θ on these ranges (``docs/sbc.md``)
GEN_PRIOR = {
    "x_G": (-5e-3, 5e-3),
    "y_G": (-5e-3, 5e-3),
    "z_G": (-5e-3, 5e-3),
    "log_a": (np.log(0.035), np.log(0.05)),
    "log_b": (np.log(0.022), np.log(0.032)),
    "log_c": (np.log(0.01), np.log(0.02)),
    "xi": (0.0, np.pi),
    "psi": (0.0, np.pi),
    "zeta": (-np.pi, np.pi),
    "log_n": (np.log(1.5), np.log(6.0)),
    "log_sigma": (np.log(2e-4), np.log(4.5e-4)),
}

#: symmetry-invariant quantities that are ranked: centre (m), sorted semi-axes (m), n (1), σ (m), volume (m³)
QUANTITIES = ("x_G", "y_G", "z_G", "a_1", "a_2", "a_3", "n", "sigma", "volume")

#: mesh resolution of the area term (an inscribed cube-sphere mesh, one octant used; even, so that the octant's
#: boundary lies on mesh lines)
AREA_RES = 16


class SBCResult(NamedTuple):
    """Result of :func:`sbc`.

    names : tuple of str
        The ranked quantities (:data:`QUANTITIES`).
    truths : (N, Q) float
        True values, SI units.
    draws : (N, L, Q) float
        The thinned posterior draws of each data set.
    ranks : (N, Q) int
        Number of draws below the truth, in {0, …, L}.
    coverage : (Q,) float
        Fraction of data sets whose truth lies in the central interval of level ``level`` (from the ranks).
    coverage_expected : float
        Exact coverage under calibration for L draws (the interval is the k-th to (L+1−k)-th order statistic).
    chi2_p : (Q,) float
        p-values of the chi-square test of uniform binned ranks (``n_bins`` bins).
    n_bins : int
    level : float
    tau_max : (N,) float
        Largest autocorrelation time of each chain, steps.
    acceptance : (N,) float
    short : int
        Chains with fewer than L thinned draws (their draws were taken from the unthinned chain).
    seconds : float
    settings : dict
    """

    names: tuple
    truths: np.ndarray
    draws: np.ndarray
    ranks: np.ndarray
    coverage: np.ndarray
    coverage_expected: float
    chi2_p: np.ndarray
    n_bins: int
    level: float
    tau_max: np.ndarray
    acceptance: np.ndarray
    short: int
    seconds: float
    settings: dict

    def to_dict(self) -> dict:
        """JSON-ready summary (no draws)."""
        return {
            "settings": self.settings,
            "quantities": list(self.names),
            "n_datasets": int(self.ranks.shape[0]),
            "n_draws": int(self.draws.shape[1]),
            "level": self.level,
            "coverage": dict(zip(self.names, map(float, self.coverage), strict=True)),
            "coverage_expected": self.coverage_expected,
            "coverage_pooled": float(self.coverage.mean()),
            "chi2_p": dict(zip(self.names, map(float, self.chi2_p), strict=True)),
            "n_bins": self.n_bins,
            "ranks": {k: self.ranks[:, i].tolist() for i, k in enumerate(self.names)},
            "tau_max": {"median": float(np.median(self.tau_max)), "max": float(np.max(self.tau_max))},
            "acceptance_median": float(np.median(self.acceptance)),
            "short_chains": self.short,
            "seconds": self.seconds,
        }


def prior_box() -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper corners (11,) of :data:`GEN_PRIOR` in θ order (``contact.PARAM_NAMES``)."""
    lo = np.array([GEN_PRIOR[k][0] for k in cm.PARAM_NAMES])
    hi = np.array([GEN_PRIOR[k][1] for k in cm.PARAM_NAMES])
    return lo, hi


def draw_prior(rng: np.random.Generator) -> np.ndarray:
    """One truth θ (11,) from :data:`GEN_PRIOR`."""
    lo, hi = prior_box()
    return lo + (hi - lo) * rng.random(lo.size)


def simulate_points(theta, n_points: int, rng: np.random.Generator) -> np.ndarray:
    """Contact points (M, 3) m: area-uniform on the surface of θ, moved along the normal by N(0, σ²)."""
    s = cm.shape_of(jnp.asarray(theta, dtype=jnp.float64))
    foot = sample_surface(s, n_points, seed=rng)
    nrm = np.asarray(ne.normals(s, jnp.asarray(foot)))
    return foot + np.exp(theta[10]) * rng.normal(size=(n_points, 1)) * nrm


def invariants(thetas) -> np.ndarray:
    """Symmetry-invariant quantities (…, 9) of θ (…, 11): centre, sorted axes a₁ ≥ a₂ ≥ a₃, n, σ, volume (SI)."""
    t = np.asarray(thetas, float)
    axes = -np.sort(-np.exp(t[..., 3:6]), axis=-1)
    n = np.exp(t[..., 9])
    vol = 8.0 * np.prod(axes, axis=-1) * np.exp(3 * gammaln(1 + 1 / n) - gammaln(1 + 3 / n))
    return np.concatenate([t[..., 0:3], axes, n[..., None], np.exp(t[..., 10:11]), vol[..., None]], axis=-1)


def _octant_mesh():
    """Directions (V, 3) and the faces (F, 3) of the cube-sphere mesh that lie in the positive octant."""
    d, f = cube_sphere(AREA_RES)
    return d, f[np.all(d[f] >= 0.0, axis=(1, 2))]


def _mesh_area(theta, dirs, faces):
    """Area m² of the inscribed mesh of θ's surface: 8 × its positive octant (the surface is symmetric under
    sign flips of the local axes; rotation and centre do not matter)."""
    Y = ne.unit_nsphere(dirs, jnp.exp(theta[9])) * jnp.exp(theta[3:6])
    e1 = Y[faces[:, 1]] - Y[faces[:, 0]]
    e2 = Y[faces[:, 2]] - Y[faces[:, 0]]
    return 4.0 * jnp.sum(jnp.linalg.norm(jnp.cross(e1, e2), axis=-1))


def _one_log_prob(area_term: bool, likelihood_power: float):
    lo, hi = prior_box()
    bounds = cm.Bounds(jnp.asarray(lo), jnp.asarray(hi))
    d, f = _octant_mesh()
    dirs, faces = jnp.asarray(d), jnp.asarray(f)
    power = float(likelihood_power)

    def one(theta, pts):
        t = cm.clip_to_box(theta, bounds)
        ll = cm.log_likelihood(t, pts, np.inf)
        if area_term:
            ll = ll - pts.shape[0] * jnp.log(_mesh_area(t, dirs, faces))
        out = cm.log_prior(theta, bounds) + power * ll
        return jnp.where(jnp.isnan(out), -jnp.inf, out)

    return one


def make_sbc_log_prob(*, area_term: bool = False, likelihood_power: float = 1.0):
    """The SBC log-posterior ``f(thetas (W, 11), points (M, 3)) -> (W,)`` (NumPy in and out), jitted once.

    log p(θ | x) = p · [log_likelihood(θ, x; ν = ∞) − M log A(θ) (if ``area_term``)] + log GEN_PRIOR(θ).

    Parameters
    ----------
    area_term : bool
        Add the area normaliser −M log A(θ) of area-uniform points alone (default False: the package's own
        likelihood, which ``docs/sbc.md`` shows to be the closer of the two to the exact density).
    likelihood_power : float
        Exponent p of the likelihood; p > 1 makes the posterior about √p times too narrow, an overconfident
        posterior for negative controls. 1 for the honest posterior.
    """
    batched = jax.jit(jax.vmap(_one_log_prob(area_term, likelihood_power), in_axes=(0, None)))

    def logp(thetas, points):
        return np.asarray(
            batched(jnp.asarray(np.atleast_2d(thetas), dtype=jnp.float64), jnp.asarray(points, dtype=jnp.float64))
        )

    return logp


class _Lockstep:
    """Evaluates the log-posteriors of K emcee samplers, one per data set and thread, in one JAX call per round.

    A round closes when every sampler still running has posted a request; the last to post evaluates all of
    them at once. Requests (the start ensemble, or the W/2 or W/4 walkers that emcee's DE and snooker moves
    update at a time) are cut into chunks of W/4 walkers and the data-set axis is padded to K, so that one
    compiled shape serves every round. Results are per slot, hence independent of thread scheduling.
    """

    def __init__(self, fn, points: np.ndarray, chunk: int, k: int):
        self.fn, self.chunk, self.k = fn, chunk, k
        self.pts = jnp.asarray(np.concatenate([points, np.repeat(points[:1], k - len(points), axis=0)]))
        self.cv = threading.Condition()
        self.active = len(points)
        self.pending: dict = {}
        self.results: dict = {}
        self.round = 0
        self.error: BaseException | None = None

    def _evaluate(self) -> None:
        slots = sorted(self.pending)
        chunks = {i: np.asarray(self.pending[i], float).reshape(-1, self.chunk, 11) for i in slots}
        out: dict = {i: [] for i in slots}
        for c in range(max(len(ch) for ch in chunks.values())):
            x = np.stack(
                [chunks[i][min(c, len(chunks[i]) - 1)] for i in slots] + [chunks[slots[0]][0]] * (self.k - len(slots))
            )
            y = np.asarray(self.fn(jnp.asarray(x), self.pts[np.array(slots + [slots[0]] * (self.k - len(slots)))]))
            for j, i in enumerate(slots):
                if c < len(chunks[i]):
                    out[i].append(y[j])
        self.results.update({i: np.concatenate(o) for i, o in out.items()})

    def _close_round(self) -> None:  # called with the lock held
        if self.pending and len(self.pending) == self.active:
            try:
                self._evaluate()
            except BaseException as e:  # handed to every waiting sampler
                self.error = e
            self.pending = {}
            self.round += 1
            self.cv.notify_all()

    def call(self, i: int, thetas) -> np.ndarray:
        with self.cv:
            if self.error is None:
                self.pending[i] = thetas
                r = self.round
                self._close_round()
                while self.round == r:
                    self.cv.wait()
            if self.error is not None:
                raise RuntimeError("SBC log-posterior evaluation failed") from self.error
            return self.results.pop(i)

    def done(self) -> None:
        with self.cv:
            self.active -= 1
            self._close_round()

    def run(self, i: int, fn, *args, **kwargs):
        """``fn(logp, *args, **kwargs)`` with slot ``i``'s log-posterior; leaves the lockstep when it returns."""
        try:
            return fn(lambda t: self.call(i, t), *args, **kwargs)
        finally:
            self.done()


def posterior_draws(
    logp,
    theta_start,
    *,
    seed: int,
    walkers: int,
    steps: int,
    n_draws: int,
    progress: bool = False,
    moves=None,
    adapt: bool = False,
) -> tuple[np.ndarray, dict]:
    """Roughly independent posterior draws (n_draws, 11) of θ by emcee, started in a ball around ``theta_start``.

    ``logp`` maps walkers (W, 11) to log-posteriors (W,); ``moves`` are emcee moves (default
    :func:`bayestouch.inference.sampler.default_moves`; with ``adapt`` the adaptive sampler of
    :func:`bayestouch.inference.run.run_contact_fit`, ``sample(..., adapt=True)``). Burn-in ``max(2τ, steps/4)`` (at
    most half the chain; adaptive: after the first adaptation), then thinning by ⌈τ⌉, then ``n_draws`` drawn
    without replacement from the thinned pool (from the
    unthinned kept chain when the pool is too small; ``info["short"]``).

    Returns
    -------
    draws : (n_draws, 11) float
    info : dict
        ``tau_max`` (steps), ``acceptance``, ``short`` (bool).
    """
    rng = np.random.default_rng(seed)
    lo, hi = prior_box()
    scale = 1e-3 * (hi - lo)
    start = np.clip(
        theta_start + scale * rng.normal(size=(walkers, lo.size)), lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo)
    )
    ch = sample(
        logp,
        start,
        None,
        walkers=walkers,
        ndim=lo.size,
        seed=seed,
        steps=steps,
        progress=progress,
        moves=moves,
        adapt=adapt,
    )
    kept = ch.kept
    pool = kept[:: max(1, int(np.ceil(ch.tau_max)))].reshape(-1, lo.size)
    short = len(pool) < n_draws
    if short:
        pool = kept.reshape(-1, lo.size)
    draws = pool[rng.choice(len(pool), n_draws, replace=False)]
    return draws, {"tau_max": ch.tau_max, "acceptance": ch.acceptance, "short": short}


def ranks_of(truths, draws) -> np.ndarray:
    """Ranks (N, Q): the number of draws (N, L, Q) strictly below each truth (N, Q)."""
    return np.sum(np.asarray(draws) < np.asarray(truths)[:, None, :], axis=1)


def coverage_of(ranks, n_draws: int, level: float = 0.9) -> tuple[np.ndarray, float]:
    """Coverage (Q,) of the central ``level`` interval from the k-th to the (L+1−k)-th order statistic of L draws,
    k = round((1 − level)/2 · (L + 1)); the truth is inside iff k ≤ rank ≤ L − k. Also returns the exact
    coverage (L + 1 − 2k)/(L + 1) under calibration."""
    k = int(round((1 - level) / 2 * (n_draws + 1)))
    r = np.asarray(ranks)
    inside = (r >= k) & (r <= n_draws - k)
    return inside.mean(axis=0), (n_draws + 1 - 2 * k) / (n_draws + 1)


def uniformity_pvalues(ranks, n_draws: int, n_bins: int) -> np.ndarray:
    """Chi-square p-values (Q,) of the binned ranks (N, Q) against the uniform law on {0, …, L}.

    Rank r goes to bin ⌊r · n_bins / (L + 1)⌋; expected counts use the exact number of rank values per bin.
    """
    r = np.asarray(ranks)
    b = (r * n_bins) // (n_draws + 1)
    per_bin = np.bincount((np.arange(n_draws + 1) * n_bins) // (n_draws + 1), minlength=n_bins)
    expected = r.shape[0] * per_bin / (n_draws + 1)
    obs = np.stack([np.bincount(b[:, q], minlength=n_bins) for q in range(r.shape[1])], axis=1)
    stat = np.sum((obs - expected[:, None]) ** 2 / expected[:, None], axis=0)
    return chi2.sf(stat, n_bins - 1)


def sbc(
    n_datasets: int,
    *,
    seed: int = 0,
    n_points: int = 100,
    walkers: int = 32,
    steps: int = 800,
    n_draws: int = 99,
    progress: bool = False,
    area_term: bool = False,
    likelihood_power: float = 1.0,
    n_bins: int | None = None,
    level: float = 0.9,
    batch: int = 10,
    moves=None,
    adapt: bool = False,
) -> SBCResult:
    """Simulation-based calibration of the contact-level posterior.

    Parameters
    ----------
    n_datasets : int
        Number N of simulated data sets (truth drawn from :data:`GEN_PRIOR`).
    seed : int
        Seeds everything (truths, points, walkers, emcee, thinning) through a ``SeedSequence``.
    n_points : int
        Contact points M per data set.
    walkers, steps : int
        emcee ensemble size and chain length per data set.
    n_draws : int
        Posterior draws L per data set (ranks lie in {0, …, L}).
    progress : bool
        Print one line per data set.
    area_term, likelihood_power
        See :func:`make_sbc_log_prob` (``likelihood_power > 1``: a deliberately overconfident posterior).
    n_bins : int, optional
        Rank-histogram bins of the chi-square test; default about N/8 (≥ 2, ≤ 20), so that expected counts ≥ 5.
    level : float
        Level of the central intervals whose coverage is reported.
    batch : int
        Data sets sampled side by side (one thread and one emcee sampler each; their log-posteriors are
        evaluated together in one JAX call per step, which amortises the per-call overhead).
    moves : callable, optional
        Returns fresh emcee moves for each chain (default :func:`bayestouch.inference.sampler.default_moves`).
    adapt : bool
        Sample each data set with the adaptive sampler that :func:`bayestouch.inference.run.run_contact_fit` uses
        (:func:`bayestouch.inference.sampler.adaptive_moves`), which is what the calibration then checks.
    """
    for name, v, least in (
        ("n_datasets", n_datasets, 2),
        ("n_points", n_points, 10),
        ("walkers", walkers, 24),
        ("steps", steps, 100),
        ("n_draws", n_draws, 9),
        ("batch", batch, 1),
    ):
        if int(v) != v or v < least:
            raise BadInput(f"{name}: expected an integer >= {least}, got {v!r}")
    if walkers % 4:
        raise BadInput(f"walkers: expected a multiple of 4, got {walkers}")
    if not 0 < level < 1:
        raise BadInput(f"level: expected a number in (0, 1), got {level!r}")
    n_bins = int(n_bins or min(20, max(2, n_datasets // 8)))
    t0 = time.perf_counter()
    fn = jax.jit(jax.vmap(jax.vmap(_one_log_prob(area_term, likelihood_power), in_axes=(0, None))))
    cases = []
    for child in np.random.SeedSequence(seed).spawn(n_datasets):
        rng = np.random.default_rng(child)
        theta = draw_prior(rng)
        cases.append((theta, simulate_points(theta, n_points, rng), int(rng.integers(2**31 - 1))))
    truths, draws, taus, accs, short = [], [], [], [], 0
    for g0 in range(0, n_datasets, batch):
        group = cases[g0 : g0 + batch]
        lock = _Lockstep(fn, np.stack([c[1] for c in group]), walkers // 4, min(batch, n_datasets))
        with ThreadPoolExecutor(len(group)) as pool:
            futures = [
                pool.submit(
                    lock.run,
                    i,
                    posterior_draws,
                    c[0],
                    seed=c[2],
                    walkers=walkers,
                    steps=steps,
                    n_draws=n_draws,
                    moves=moves() if moves else None,
                    adapt=adapt,
                )
                for i, c in enumerate(group)
            ]
            results = [f.result() for f in futures]
        for (theta, _, _), (d, info) in zip(group, results, strict=True):
            truths.append(invariants(theta))
            draws.append(invariants(d))
            taus.append(info["tau_max"])
            accs.append(info["acceptance"])
            short += info["short"]
        if progress:
            _log.info(
                "[sbc] %d/%d data sets, median tau_max %.0f steps, %.0f s",
                len(truths),
                n_datasets,
                np.median(taus),
                time.perf_counter() - t0,
            )
    truths, draws = np.array(truths), np.array(draws)
    ranks = ranks_of(truths, draws)
    cov, cov_exp = coverage_of(ranks, n_draws, level)
    settings = {
        "seed": seed,
        "n_points": n_points,
        "walkers": walkers,
        "steps": steps,
        "n_draws": n_draws,
        "area_term": area_term,
        "likelihood_power": likelihood_power,
        "prior": {k: list(v) for k, v in GEN_PRIOR.items()},
        "likelihood": "Gaussian (nu = inf)",
    }
    return SBCResult(
        QUANTITIES,
        truths,
        draws,
        ranks,
        cov,
        cov_exp,
        uniformity_pvalues(ranks, n_draws, n_bins),
        n_bins,
        level,
        np.array(taus),
        np.array(accs),
        short,
        time.perf_counter() - t0,
        settings,
    )


def de_moves():
    """emcee moves of every SBC chain: differential evolution alone."""
    return [(emcee.moves.DEMove(), 1.0)]


def plot_ranks(result: SBCResult, path: Path) -> None:
    from bayestouch.report import canvas

    L, N = result.draws.shape[1], result.ranks.shape[0]
    nb = result.n_bins
    fig, axs = canvas.subplots(3, 3, figsize=(10, 8), constrained_layout=True)
    edges = np.arange(nb + 1) * (L + 1) / nb
    lo, hi = binom.ppf([0.005, 0.995], N, 1 / nb)  # 99 % band of one bin's count under uniform ranks
    for ax, q in zip(axs.ravel(), range(len(result.names)), strict=True):
        ax.axhspan(lo, hi, color="0.85")
        ax.hist(result.ranks[:, q], bins=edges, color="C0", edgecolor="white")
        ax.set_title(f"{result.names[q]}: cov {result.coverage[q]:.2f}, p {result.chi2_p[q]:.2g}", fontsize=9)
        ax.set_xlim(0, L + 1)
    fig.suptitle(f"SBC ranks, {N} data sets, {L} draws (grey: 99 % band per bin)")
    fig.savefig(path, dpi=100)
