"""The emcee engine shared by every likelihood level: seeded, checkpointed, resumable, budgeted sampling and
honest convergence diagnostics. The stateful edge of the inference package (the log-density is pure).

A model plugs in as a vectorised log-probability ``logp(thetas (W, D)) -> (W,)`` (NumPy in and out, −inf
outside the prior, never NaN) and a start ensemble; :func:`sample` returns the chain after burn-in and the
numbers a summary needs.
"""

from __future__ import annotations

import signal
import threading
import time
from pathlib import Path
from typing import NamedTuple

import arviz as az
import emcee
import numpy as np
import xarray as xr
from emcee.state import State
from scipy.stats import chi2

from bayestouch.errors import BadInput, as_array, check_int, check_path, check_seed, shown
from bayestouch.inference.modes import gaussian_mixture

__all__ = [
    "Chain",
    "sample",
    "integrated_time",
    "default_moves",
    "snooker_move",
    "adaptive_moves",
    "IndependenceT",
    "IndependenceMixture",
    "HamiltonianMove",
    "leapfrog",
    "adaptation_steps",
    "convergence",
    "prune_stuck_walkers",
    "R_HAT_MAX",
    "ESS_MIN",
    "TAU_FACTOR",
    "ADAPT_FIRST",
    "fewest_kept_steps",
    "finite_proposals",
    "arrival_step",
    "tau_settled",
    "TAU_GROWTH",
    "not_converged_because",
]

#: convergence thresholds (Vehtari et al. 2021 for R-hat and bulk ESS; emcee's docs for N > 50 τ)
R_HAT_MAX = 1.01
ESS_MIN = 400.0
TAU_FACTOR = 50.0
#: largest relative growth of τ_max between two convergence checks that still counts as settled (:func:`tau_settled`)
TAU_GROWTH = 0.05
#: convergence checks are spaced by at least this fraction of the chain's length: each check reads the whole chain
#: (τ, R-hat, ESS are O(length)), so checks at a fixed interval made long runs quadratic in their length
CHECK_GROWTH = 0.1
#: a convergence check reads a long chain thinned to about this many steps, provided the thinning interval stays
#: below a tenth of τ_max (so τ, R-hat and bulk ESS are those of the whole chain to a few per cent); a check that
#: passes on the thinned chain is confirmed on the whole one
CHECK_STEPS = 2000
CHECK_STEPS_PER_TAU = 10.0
#: first step at which an adaptive run (``sample(..., adapt=True)``) fits its independence proposal; later fits at
#: twice, four times … that step
ADAPT_FIRST = 100
#: an adaptive :class:`IndependenceMixture`'s refits: the given mixture's share, the most draws EM reads and the
#: most components it tries
DEFENSIVE_SHARE = 0.2
REFIT_DRAWS = 2000
REFIT_COMPONENTS = 4


class Chain(NamedTuple):
    """Result of :func:`sample`.

    kept : (S, W, D) float
        Draws after burn-in (steps, walkers, parameters), in the sampled parametrisation.
    log_prob : (S, W) float
        Log-posterior of the kept draws.
    steps : int
        Steps in the chain file (burn-in included).
    burn : int
        Steps discarded as burn-in.
    tau_max : float
        Largest integrated autocorrelation time (steps) of the monitored quantities (the sampled parameters without
        a monitor), NaN when it cannot be estimated.
    acceptance : float or None
        Mean acceptance fraction of this call's steps (None when nothing was sampled now).
    stopped_by_budget : bool
    seconds : float
        Wall-clock time of this call.
    tau_steps : int or None
        Length (steps) of the stretch of chain τ was estimated on: the kept draws (:func:`_tau_and_burn`).
    """

    kept: np.ndarray
    log_prob: np.ndarray
    steps: int
    burn: int
    tau_max: float
    acceptance: float | None
    stopped_by_budget: bool
    seconds: float
    tau_steps: int | None = None


def snooker_move():
    """The differential-evolution snooker move of ter Braak & Vrugt (2008, Stat. Comput. 18:435, sect. 3) as
    published: project the DE difference on the unit vector from an archive point z through the walker, and accept
    with the Jacobian factor (d − 1)·log(|q − z| / |x − z|).

    emcee 3.1.6's ``DESnookerMove`` uses δ/√|δ| (not a unit vector) and half that factor, which does not keep the
    target invariant: on a Gaussian with a known posterior its variances come out about 50 % low alone and 10 %
    low as a fifth of the moves (``tests/test_sampler.py``).
    """

    class Snooker(emcee.moves.DESnookerMove):
        def get_proposal(self, s, c, random):
            ns, ndim = len(s), s.shape[1]
            nc = [len(cj) for cj in c]
            q = np.empty_like(s)
            log_jac = np.empty(ns)
            for i in range(ns):
                w = np.array([c[j][random.randint(nc[j])] for j in range(3)])
                random.shuffle(w)
                z, z1, z2 = w
                delta = s[i] - z
                dist = np.linalg.norm(delta)
                if not dist > 0:
                    # z is the walker itself (walkers started on copies of one SMC particle): no direction to
                    # move along, so the walker stays, a null move that leaves π invariant (0/0 was a NaN
                    # proposal, on which emcee stops the run)
                    q[i], log_jac[i] = s[i], 0.0
                    continue
                u = delta / dist
                q[i] = s[i] + self.gammas * np.dot(u, z1 - z2) * u
                log_jac[i] = np.log(np.linalg.norm(q[i] - z)) - np.log(dist)
            return q, (ndim - 1.0) * log_jac

    return Snooker()


def default_moves():
    """Differential-evolution moves, 80 % parallel-direction DE and 20 % snooker (ter Braak 2006; ter Braak & Vrugt
    2008): the shape parameters are strongly correlated, which affine-invariant stretch moves handle poorly."""
    return [(emcee.moves.DEMove(), 0.8), (snooker_move(), 0.2)]


def adaptation_steps(upto: int) -> list[int]:
    """The steps at which an adaptive run refits its proposal, up to ``upto``: ADAPT_FIRST · 2^k."""
    out, a = [], ADAPT_FIRST
    while a <= upto:
        out.append(a)
        a *= 2
    return out


#: largest logarithm the independence mixture exponentiates (e^700 ≈ 1e304, finite): a proposal beyond it lies
#: outside every prior and is rejected
LOG_PROPOSAL_MAX = 700.0
#: what a non-finite proposed coordinate becomes (emcee refuses infinite or NaN coordinates outright): finite, far
#: outside every prior, so the proposal is rejected as one outside the support would be
OUTSIDE = 1e300


def finite_proposals(y: np.ndarray) -> np.ndarray:
    """Proposals ``(W, D)`` with every non-finite coordinate set to ±:data:`OUTSIDE` (NaN to +): a proposal fitted to
    a degenerate ensemble (a posterior improper along one direction, e.g. contacts in one plane) can overflow, and
    emcee would stop the run on it; such a point has zero prior density and is rejected."""
    return np.nan_to_num(y, nan=OUTSIDE, posinf=OUTSIDE, neginf=-OUTSIDE)


class IndependenceT:
    """Independence Metropolis–Hastings move with a multivariate Student-t proposal fitted to earlier draws.

    Every walker proposes x' ~ t_ν(μ, Σ) independently of where it is, and accepts with probability
    min(1, π(x') g(x) / (π(x) g(x'))), g the proposal density (Hastings 1970; Tierney 1994, Ann. Stat. 22:1701,
    sect. 2.3.3). For a fixed (μ, Σ) the move leaves π invariant whatever (μ, Σ) are; a good fit only makes it
    efficient: on a near-Gaussian posterior most proposals are accepted and successive draws are almost
    independent, where differential-evolution moves need τ ≈ 40 steps in 11 dimensions. A t proposal has tails
    heavier than a Gaussian posterior's, so π/g stays bounded for light-tailed targets (uniform ergodicity,
    Tierney's Cor. 4).

    Before :meth:`fit` or :meth:`set` is first called the move hands every step to ``fallback``.

    Parameters
    ----------
    fallback : emcee move
        Used until the first fit.
    nu : float
        Degrees of freedom of the proposal.
    """

    def __init__(self, fallback, nu: float = 10.0):
        self.fallback = fallback
        self.nu = float(nu)
        self.mean: np.ndarray | None = None
        self.chol: np.ndarray | None = None

    def fit(self, draws) -> None:
        """Set the proposal's centre and scale matrix to the mean and covariance of ``draws (n, D)``."""
        x = np.asarray(draws, float)
        self.set(x.mean(axis=0), np.atleast_2d(np.cov(x.T)))

    def set(self, mean, cov) -> None:
        """Set the proposal's centre (D,) and scale matrix (D, D) (a ridge of 1e-12 of each variance keeps the
        Cholesky factor defined for a degenerate ensemble)."""
        cov = np.asarray(cov, float)
        cov = cov + np.diag(1e-12 * np.diag(cov) + 1e-300)
        self.mean, self.chol = np.asarray(mean, float).copy(), np.linalg.cholesky(cov)
        self._inv = np.linalg.inv(self.chol)

    def weight_spread(self, draws, log_prob) -> float:
        """Standard deviation of the log importance weights log π − log g over draws ``(n, D)`` of π with their
        log-densities ``log_prob (n,)``: 0 for a proposal equal to π, larger the worse g matches it (a proposal
        too narrow or too wide, or off-centre); the independence move accepts more the smaller it is."""
        lw = np.asarray(log_prob, float) - self.log_g(draws)
        return float(np.std(lw)) if np.all(np.isfinite(lw)) else float("inf")

    def log_g(self, x) -> np.ndarray:
        """Log proposal density (W,) at ``x (W, D)``, up to a constant (it cancels in the acceptance ratio)."""
        z = (np.asarray(x) - self.mean) @ self._inv.T
        return -0.5 * (self.nu + len(self.mean)) * np.log1p(np.sum(z * z, axis=1) / self.nu)

    def draw(self, random, count: int) -> np.ndarray:
        """``count`` draws (count, D) of the proposal from a ``np.random.RandomState``."""
        z = random.standard_normal((count, len(self.mean)))
        u = random.chisquare(self.nu, count)
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow is mapped outside the prior below
            y = self.mean + (z @ self.chol.T) * np.sqrt(self.nu / u)[:, None]
        return finite_proposals(y)

    def propose(self, model, state):
        if self.mean is None:
            return self.fallback.propose(model, state)
        w = state.coords.shape[0]
        q = self.draw(model.random, w)
        lp, blobs = model.compute_log_prob_fn(q)
        lnpdiff = lp - state.log_prob + self.log_g(state.coords) - self.log_g(q)
        accepted = np.log(model.random.rand(w)) < lnpdiff
        return self.fallback.update(state, State(q, log_prob=lp, blobs=blobs), accepted), accepted


class IndependenceMixture(IndependenceT):
    """Independence Metropolis–Hastings with a mixture of multivariate t components as the proposal: a kernel
    density estimate of earlier posterior draws (e.g. the particles of a tempered SMC run,
    :mod:`bayestouch.inference.smc`), each component centred on a draw with the scale of its neighbourhood, so a
    posterior with several separated modes or a curved ridge is proposed from where its mass is and walkers jump
    between modes in one step. For a fixed mixture the move leaves π invariant (Tierney 1994, sect. 2.3.3).

    An ``adaptive`` mixture is refitted by :func:`sample` at its adaptation steps (:meth:`refit`): a Gaussian
    mixture fitted to the chain's own recent draws takes ``1 − defensive`` of the weight and the mixture given here
    keeps ``defensive`` (a defensive mixture, Hesterberg 1995, Technometrics 37:185), so a mode the start found and
    the chain has not visited stays one proposal away. A refit is kept only when it matches the chain's draws
    better than the mixture in force (:meth:`IndependenceT.weight_spread`). A mixture fitted to particles of the
    wrong shape (a Laplace component for a curved ridge, an SMC run that found another mode) is thus replaced by
    one of the posterior's shape as the chain learns it; the kernel changes finitely often, so the chain's law
    converges to π as a fixed kernel's would (as for :class:`IndependenceT`'s refits).

    Parameters
    ----------
    centres : (J, D) float
        Component centres.
    chols : (J, D, D) float
        Cholesky factors of the components' scale matrices.
    fallback : emcee move
        Only for emcee's bookkeeping (``update``).
    nu : float
        Degrees of freedom of every component.
    weights : (J,) float, optional
        Component probabilities (normalised here); default equal.
    log_columns : sequence of int, optional
        Coordinates that are positive (e.g. outlier fractions near 0): the mixture lives in the space where they
        are logarithms (``centres`` and ``chols`` there), so a proposal never leaves their support and a mass
        piled near 0 is a Gaussian in log space; the density carries the Jacobian Π 1/x_j.
    adaptive : bool
        Refit to the chain's draws at :func:`sample`'s adaptation steps (default: fixed).
    defensive : float
        Weight the given mixture keeps in an adaptive refit, in (0, 1).
    """

    def __init__(
        self,
        centres,
        chols,
        fallback,
        nu: float = 10.0,
        weights=None,
        log_columns=(),
        *,
        adaptive: bool = False,
        defensive: float = DEFENSIVE_SHARE,
    ):
        super().__init__(fallback, nu)
        if not 0.0 < float(defensive) < 1.0:
            raise ValueError(f"defensive: expected a weight in (0, 1), got {defensive!r}")
        self.log_columns = np.asarray(log_columns, int)
        self.adaptive = bool(adaptive)
        self.defensive = float(defensive)
        centres = np.asarray(centres, float)
        w = np.ones(len(centres)) if weights is None else np.asarray(weights, float)
        if w.shape != (len(centres),) or not np.all(w >= 0) or not w.sum() > 0:
            raise ValueError(f"weights: expected {len(centres)} non-negative numbers, not all 0")
        self._base = (centres, np.asarray(chols, float), w / w.sum())
        self.reset()

    def _use(self, centres, chols, weights) -> None:
        self.centres, self.chols, self.weights = centres, chols, weights
        self.mean = self.centres.mean(axis=0)  # marks the move as fitted
        self._invs = np.linalg.inv(self.chols)
        with np.errstate(divide="ignore"):
            self._log_w = np.log(self.weights)
        self._log_det = np.sum(np.log(np.abs(np.diagonal(self.chols, axis1=1, axis2=2))), axis=1) - self._log_w

    def reset(self) -> None:
        """Put the mixture given at construction back in force (a resumed run replays its refits from it)."""
        self._use(*self._base)

    def fit(self, draws) -> None:  # the single-t refit of IndependenceT does not apply; see refit
        return None

    def set(self, mean, cov) -> None:
        return None

    def refit(self, draws, log_prob, rng: np.random.Generator) -> bool:
        """Refit an ``adaptive`` mixture to posterior draws ``draws (n, D)`` with log-densities ``log_prob (n,)``:
        a Gaussian mixture (EM, components by BIC; :func:`bayestouch.inference.modes.gaussian_mixture`) on at most
        :data:`REFIT_DRAWS` of them (chosen with ``rng``), in the mixture's coordinates, beside the defensive share
        of the given mixture. Replaces the mixture in force only when its log importance weights over ``draws``
        spread less; returns whether it did (always False for a fixed mixture)."""
        if not self.adaptive:
            return False
        x = np.asarray(draws, float)
        lp = np.asarray(log_prob, float)
        ok = np.isfinite(lp) & np.all(x[:, self.log_columns] > 0, axis=1)
        x, lp = x[ok], lp[ok]
        if len(x) <= 2 * (x.shape[1] + 1):
            return False
        if len(x) > REFIT_DRAWS:
            keep = rng.choice(len(x), REFIT_DRAWS, replace=False)
            x, lp = x[keep], lp[keep]
        y = x.copy()
        y[:, self.log_columns] = np.log(y[:, self.log_columns])
        w, mu, cov = gaussian_mixture(y, rng, max_components=REFIT_COMPONENTS)
        diag = np.arange(cov.shape[1])
        cov[:, diag, diag] += 1e-10 * cov[:, diag, diag] + 1e-300  # keeps each Cholesky factor defined
        base_c, base_l, base_w = self._base
        cand = (
            np.concatenate([mu, base_c]),
            np.concatenate([np.linalg.cholesky(cov), base_l]),
            np.concatenate([(1.0 - self.defensive) * w, self.defensive * base_w]),
        )
        now = self.weight_spread(x, lp)
        old = (self.centres, self.chols, self.weights)
        self._use(*cand)
        if self.weight_spread(x, lp) < now:
            return True
        self._use(*old)
        return False

    def draw(self, random, count: int) -> np.ndarray:
        j = random.choice(len(self.centres), size=count, p=self.weights)
        z = random.standard_normal((count, self.centres.shape[1]))
        u = random.chisquare(self.nu, count)
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow is mapped outside the prior below
            y = self.centres[j] + np.einsum("wij,wj->wi", self.chols[j], z) * np.sqrt(self.nu / u)[:, None]
            y[:, self.log_columns] = np.exp(np.minimum(y[:, self.log_columns], LOG_PROPOSAL_MAX))
        return finite_proposals(y)

    def log_g(self, x) -> np.ndarray:
        """Log proposal density (W,) at ``x (W, D)`` up to a constant; −inf where a ``log_columns`` entry is ≤ 0."""
        y = np.array(np.atleast_2d(x), dtype=float)
        pos = y[:, self.log_columns]
        ok = np.all(pos > 0, axis=1)
        logs = np.log(np.where(pos > 0, pos, 1.0))
        y[:, self.log_columns] = logs
        z = np.einsum("jab,wjb->wja", self._invs, y[:, None, :] - self.centres[None])
        q = np.sum(z * z, axis=2)  # (W, J)
        d = self.centres.shape[1]
        lc = -0.5 * (self.nu + d) * np.log1p(q / self.nu) - self._log_det[None]  # (W, J)
        top = lc.max(axis=1)  # finite: a component of positive weight has a finite density everywhere
        out = top + np.log(np.sum(np.exp(lc - top[:, None]), axis=1))
        return np.where(ok, out - np.sum(logs, axis=1), -np.inf)


def leapfrog(x, r, chols, eps: float, steps: int, grad):
    """``steps`` ≥ 1 leapfrog steps of size ``eps`` from positions ``x (W, D)`` and momenta ``r (W, D)``, the
    momenta in coordinates whitened by each row's Cholesky factor ``chols (W, D, D)`` (position moves by
    ε L r); ``grad(y) -> (aux, Lᵀ ∇log π(y))``. Returns the end positions, the end momenta and ``aux`` of the last
    position."""
    _, g = grad(x)
    r = r + 0.5 * eps * g
    y = x
    for i in range(steps):
        y = y + eps * np.einsum("wij,wj->wi", chols, r)
        aux, g = grad(y)
        r = r + (eps if i < steps - 1 else 0.5 * eps) * g
    return y, r, aux


class HamiltonianMove(emcee.moves.Move):
    """Hamiltonian Monte Carlo (Neal 2011, Handbook of MCMC ch. 5) of every walker independently, as an emcee move.

    Walker w's momentum is N(0, I) in coordinates whitened by its own fixed Cholesky factor ``chols[w]`` (an
    inverse mass matrix: e.g. the local posterior covariance where the walker started), the leapfrog step size is
    ``eps`` and the number of leapfrog steps is drawn uniformly from 1 … ``steps`` each time. A walker's kernel
    depends only on its index, so it is a reversible Metropolis kernel that leaves π invariant; walkers do not
    interact, so walkers in separated modes stay apart (and R-hat says so) unless another move carries them
    across.

    Parameters
    ----------
    gradients : callable
        ``(W, D) -> (log_prior (W,), log_lik (W,), ∇log_prior (W, D), ∇log_lik (W, D))``
        (e.g. ``make_log_prob(...)[0].parts`` of :mod:`bayestouch.inference.contact`).
    chols : (W, D, D) float
    eps : float
    steps : int
    """

    def __init__(self, gradients, chols, eps: float, steps: int = 8):
        self.gradients = gradients
        self.chols = np.asarray(chols, float)
        self.eps = float(eps)
        self.steps = int(steps)

    def _grad(self, y):
        _, _, ga, gb = self.gradients(y)
        return None, np.einsum("wji,wj->wi", self.chols, ga + gb)

    def propose(self, model, state):
        x = state.coords
        w, d = x.shape
        if self.chols.shape[0] != w:
            raise ValueError(f"HamiltonianMove: {self.chols.shape[0]} mass matrices for {w} walkers")
        steps = model.random.randint(1, self.steps + 1)
        r0 = model.random.standard_normal((w, d))
        y, r, _ = leapfrog(x, r0, self.chols, self.eps, steps, self._grad)
        lp, blobs = model.compute_log_prob_fn(y)
        with np.errstate(invalid="ignore", over="ignore"):
            log_a = (lp - 0.5 * np.sum(r * r, axis=1)) - (state.log_prob - 0.5 * np.sum(r0 * r0, axis=1))
        accepted = np.log(model.random.rand(w)) < np.where(np.isfinite(log_a), log_a, -np.inf)
        return self.update(state, State(y, log_prob=lp, blobs=blobs), accepted), accepted


def adaptive_moves(nu: float = 10.0):
    """The adaptive run's moves: 80 % :class:`IndependenceT` with ``nu`` degrees of freedom (default 10;
    differential evolution until its first fit, unless :func:`sample` is given a ``proposal``), 15 % DE and 5 %
    snooker, so a posterior far from a t distribution still mixes (at a fifth of the pace of :func:`default_moves`)
    while a near-Gaussian one mixes in a few steps. Raw fits use ν = 30 with their Laplace start as the proposal
    (``bayestouch.inference.raw.RAW_PROPOSAL_NU``: τ ≈ 2 steps, 300 steps on the standard scenario).

    Measured on the 1000-point contact posterior of ``benchmarks/bench_sampling.py`` (32 walkers, 2 seeds): τ 4–6
    steps and a converged stop after 600–650 steps, against ν = 5 at 60 % (τ 7–8, 750–900 steps), ν = 20 at 90 %
    (τ 4, 900–950 steps: R-hat is slower to settle) and :func:`default_moves` (τ 45, 8000 steps)."""
    indep = IndependenceT(emcee.moves.DEMove(), nu=nu)
    return [(indep, 0.8), (emcee.moves.DEMove(), 0.15), (snooker_move(), 0.05)]


def _buffered_hdf_backend(path: Path, flush_s: float):
    """An emcee HDF5 backend that keeps steps in memory and writes them in one transaction at most every
    ``flush_s`` seconds (and on :meth:`flush`): emcee's own writes every step at ~7–10 ms a step, as long as a
    whole step of a 1000-point likelihood. A run killed at any moment loses at most ``flush_s`` of sampling; every
    step already on disk stays bit for bit."""

    class Buffered(emcee.backends.HDFBackend):
        def __init__(self, filename):
            super().__init__(filename)
            self._rows: list = []
            self._last = time.monotonic()

        def save_step(self, state, accepted):
            if not self._rows:  # emcee's own check reads the file three times: once per batch is enough
                self._check(state, accepted)
            self._rows.append(
                (
                    np.array(state.coords),
                    np.array(state.log_prob),
                    np.array(accepted),
                    None if state.blobs is None else np.array(state.blobs),
                    state.random_state,
                )
            )
            if time.monotonic() - self._last >= flush_s:
                self.flush()

        def flush(self):
            if self._rows:
                with self.open("a") as f:
                    g = f[self.name]
                    it = int(g.attrs["iteration"])
                    k = len(self._rows)
                    g["chain"][it : it + k] = np.stack([r[0] for r in self._rows])
                    g["log_prob"][it : it + k] = np.stack([r[1] for r in self._rows])
                    if self._rows[0][3] is not None:
                        g["blobs"][it : it + k] = np.stack([r[3] for r in self._rows])
                    g["accepted"][:] += np.sum([r[2] for r in self._rows], axis=0)
                    for i, v in enumerate(self._rows[-1][4]):
                        g.attrs[f"random_state_{i}"] = v
                    g.attrs["iteration"] = it + k
                self._rows = []
            self._last = time.monotonic()

    return Buffered(str(path))


def prune_stuck_walkers(
    ensemble, log_prob, rng: np.random.Generator, *, tail: float = 1e-4, jitter: float = 1e-2
) -> tuple[np.ndarray, int]:
    """Replace walkers stuck far below the best of a warm-start ensemble.

    An ensemble carried over from another run (an exploration's short updates) can hold walkers left in a local
    mode whose density is many nats below the rest; an ensemble sampler rarely moves them out (a walker moves with
    the differences of the others), so they inflate R-hat and bias the summaries. Near a mode, the log-density of a
    D-dimensional posterior lies below its maximum by ½ χ²_D; walkers lower than ``max − ½ χ²_D(1 − tail)`` are
    therefore implausible as posterior draws, and each is replaced by a random plausible walker plus Gaussian
    jitter of ``jitter`` times the plausible walkers' sd per coordinate.

    Parameters
    ----------
    ensemble : (W, D) float
    log_prob : (W,) float
        Log-density of each walker (−inf counts as stuck).
    rng : np.random.Generator
    tail : float
        Probability that a true posterior draw is pruned (per walker).
    jitter : float

    Returns
    -------
    ensemble : (W, D) float
        The new ensemble (a copy).
    replaced : int
        How many walkers were replaced.
    """
    ens = np.array(ensemble, float)
    lp = np.asarray(log_prob, float)
    finite = np.isfinite(lp)
    if not finite.any():
        raise BadInput("start: every walker of the starting ensemble has zero posterior density")
    cut = lp[finite].max() - 0.5 * chi2.isf(tail, ens.shape[1])
    good = finite & (lp >= cut)
    bad = np.flatnonzero(~good)
    if len(bad):
        sd = ens[good].std(axis=0) if good.sum() > 1 else np.abs(ens[good][0]) * 1e-3 + 1e-9
        pick = rng.choice(np.flatnonzero(good), size=len(bad))
        ens[bad] = ens[pick] + jitter * sd * rng.standard_normal((len(bad), ens.shape[1]))
    return ens, int(len(bad))


def _burn_in(n_done: int, tau_max: float) -> int:
    """Steps to discard: twice the largest autocorrelation time, at least a quarter and at most half the chain."""
    return int(min(n_done // 2, max(2 * tau_max, n_done // 4))) if np.isfinite(tau_max) else n_done // 2


def integrated_time(chain) -> np.ndarray:
    """Integrated autocorrelation time (D,) of each parameter of ``chain (n, W, D)``, in steps.

    emcee's estimator (``emcee.autocorr.integrated_time(chain, tol=0)``: the normalised autocorrelation function of
    each walker by FFT, averaged over walkers, summed up to Sokal's automatic window c = 5), computed with one FFT
    over every walker and parameter at once instead of one per series — the convergence checks call it every 50
    steps. Equal to emcee's to rounding (``tests/test_sampler.py``).
    """
    x = np.asarray(chain, float)
    n = x.shape[0]
    size = 1 << max(n - 1, 0).bit_length()
    f = np.fft.rfft(x - x.mean(axis=0), n=2 * size, axis=0)
    acf = np.fft.irfft(f * np.conj(f), n=2 * size, axis=0)[:n]
    with np.errstate(invalid="ignore", divide="ignore"):
        acf = np.mean(acf / acf[0], axis=1)  # (n, D), averaged over walkers
    taus = 2.0 * np.cumsum(acf, axis=0) - 1.0
    m = np.arange(n)[:, None] < 5.0 * taus
    window = np.where(m.any(axis=0), np.argmin(m, axis=0), n - 1)
    return taus[window, np.arange(x.shape[2])]


def _stationary(log_prob) -> bool:
    """Whether the log-densities ``log_prob (n, W)`` of a stretch of chain look stationary: the mean over its second
    half lies within one sd of the log-density (over walkers and steps of that half; ≈ √(D/2) at stationarity) of
    the mean over its first half. An ensemble still climbing towards the mode fails (its mean rises by many sds),
    and an independence proposal fitted to such draws would only waste proposals."""
    lp = np.asarray(log_prob, float)
    if lp.shape[0] < 4 or not np.all(np.isfinite(lp)):
        return False
    h = lp.shape[0] // 2
    return bool(abs(lp[h:].mean() - lp[:h].mean()) < lp[h:].std())


def _thinned_time(seg: np.ndarray) -> np.ndarray:
    """:func:`integrated_time` of ``seg (n, W, D)`` from every k-th step, k = n // :data:`CHECK_STEPS`, times k,
    where the thinned chain's largest τ is at least :data:`CHECK_STEPS_PER_TAU` steps (τ_k ≈ τ/k there: thinning
    by k ≤ τ/10 loses nothing of the estimate); from the whole chain otherwise. Only the largest τ is exact this
    way: a parameter with τ below k comes out near k."""
    k = len(seg) // CHECK_STEPS
    if k > 1:
        tau = integrated_time(seg[::k])
        if np.all(np.isfinite(tau)) and np.max(tau) >= CHECK_STEPS_PER_TAU:
            return tau * k
    return integrated_time(seg)


def _skipped(n: int, adapt: bool, first: int) -> int:
    """Steps of a chain of ``n`` before the stretch τ and the burn-in are taken on: an adaptive chain's first
    ``first`` (before its first adaptation), when it is longer."""
    return first if adapt and n > first else 0


def fewest_kept_steps(steps: int, adapt: bool, first: int = ADAPT_FIRST) -> int:
    """The fewest steps a chain of ``steps`` keeps after burn-in (:func:`_tau_and_burn`: the burn-in is at most half
    of the stretch after the skipped steps)."""
    seg = steps - _skipped(steps, adapt, first)
    return seg - _burn_in(seg, float("nan"))


def arrival_step(log_prob) -> int:
    """The first step by which every walker has reached the posterior's typical set: the largest over walkers of
    the first step whose log-density (``log_prob (n, W)``) is at least the median of the second half's (all
    walkers pooled). An ensemble started in the typical set arrives within a few steps (each step above the
    median with probability about ½ once there); one climbing towards it, when its last walker gets there; a
    walker that never does gives n."""
    lp = np.asarray(log_prob, float)
    n = lp.shape[0]
    tail = lp[n // 2 :]
    if n < 2 or not np.isfinite(tail).any():
        return 0
    above = lp >= np.median(tail[np.isfinite(tail)])
    first = np.where(above.any(axis=0), np.argmax(above, axis=0), n)
    return int(first.max())


def _tau_and_burn(
    chain: np.ndarray, adapt: bool, first: int = ADAPT_FIRST, thin: bool = False, log_prob=None
) -> tuple[np.ndarray, int, int]:
    """Integrated autocorrelation times (D,) of the kept draws of ``chain (n, W, D)``, the burn-in and the length of
    the kept stretch τ was estimated on.

    An adaptive chain is judged after its first adaptation (step ``first``), where the kernel of its kept draws
    begins. The burn-in is :func:`_burn_in` of that stretch with τ of the whole stretch, and at least the step at
    which the walkers arrived in the typical set (:func:`arrival_step` of ``log_prob (n, W)``, when given), at most
    half the stretch; τ itself is then estimated on the draws kept. A τ estimated over a climb measures the climb,
    not the chain's mixing: an SBC fit whose walkers climbed 45 nats in their first 5,000 steps and then mixed with
    τ ≈ 40 steps reported τ = 2,000 and "not converged" after 20,000 steps (``docs/contact_model.md``). ``thin``: τ of a
    long chain from a thinned copy (:func:`_thinned_time`; the convergence checks), whose largest τ only is
    exact."""
    skip = _skipped(chain.shape[0], adapt, first)
    seg = chain[skip:]
    time_of = _thinned_time if thin else integrated_time
    if len(seg) <= 1:
        return np.full(chain.shape[2], np.nan), skip + _burn_in(len(seg), float("nan")), len(seg)
    whole = time_of(seg)
    burn = _burn_in(len(seg), float(np.nanmax(whole)) if np.isfinite(whole).any() else float("nan"))
    if log_prob is not None:
        burn = min(len(seg) // 2, max(burn, arrival_step(np.asarray(log_prob, float)[skip:])))
    kept = seg[burn:]
    tau = time_of(kept) if len(kept) > 1 else np.full(chain.shape[2], np.nan)
    return tau, skip + burn, len(kept)


def _next_check(length: int, check_every: int) -> int:
    """The chain length of the convergence check after one at ``length`` steps: ``max(check_every, ⌈CHECK_GROWTH ·
    length⌉)`` steps later, rounded up to a multiple of ``check_every``."""
    gap = max(check_every, int(np.ceil(CHECK_GROWTH * length)))
    return -(-(length + gap) // check_every) * check_every


def monitored(chain: np.ndarray, monitor=None) -> np.ndarray:
    """``chain (n, W, D)`` mapped draw by draw through ``monitor`` ((N, D) → (N, Q)) to (n, W, Q); the chain itself
    without one."""
    if monitor is None:
        return chain
    n, w, d = chain.shape
    return np.asarray(monitor(chain.reshape(-1, d))).reshape(n, w, -1)


class _MonitoredChain:
    """The monitored quantities of a growing chain (:func:`monitored`), each step mapped once: a convergence check
    maps only the steps added since the last one (the monitor is applied draw by draw)."""

    def __init__(self, monitor):
        self.monitor = monitor
        self.values: np.ndarray | None = None

    def extend(self, chain: np.ndarray) -> np.ndarray:
        """The monitored ``chain (n, W, D)`` (n, W, Q); its first steps must be those seen before."""
        if self.monitor is None:
            return chain
        done = 0 if self.values is None else len(self.values)
        if done < len(chain):
            new = monitored(chain[done:], self.monitor)
            self.values = new if self.values is None else np.concatenate([self.values, new])
        return self.values


def tau_settled(tau, old_tau, growth: float = TAU_GROWTH) -> bool:
    """Whether the largest integrated autocorrelation time of ``tau (D,)`` (steps) has stopped growing since the
    check before, ``old_tau (D,)``: finite, and τ_max < (1 + ``growth``) × the earlier τ_max.

    The length rule (a stretch longer than 50 τ_max) is only as good as τ_max, which a short chain underestimates
    while it is still finding its slower directions: a τ_max that grows says the chain is too short to judge. One
    that falls does not: with an adaptive proposal the later draws mix faster, and τ_max falls as they come to
    dominate the kept stretch (``docs/contact_model.md``, "Sampling"); the length rule with the smaller τ_max then
    holds with more margin, and R-hat and the bulk ESS still have to pass."""
    t, o = np.asarray(tau, float), np.asarray(old_tau, float)
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(o))):
        return False
    return bool(np.max(t) < (1.0 + growth) * np.max(o))


def _looks_converged(chain: np.ndarray, tau, old_tau, burn: int, length: int) -> bool:
    """The stopping rule on ``chain (n, W, Q)`` (the monitored quantities): the stretch τ was estimated on is longer
    than 50 τ_max, τ_max no longer growing (:func:`tau_settled`: the estimate the length rule relies on), and on
    the draws after burn-in every R-hat < 1.01 and every bulk ESS > 400 (ArviZ, walkers as chains) — the summary's
    own criterion."""
    if not (tau_settled(tau, old_tau) and length > TAU_FACTOR * np.max(tau)):
        return False
    kept = chain[burn:]

    def passes(draws):
        ds = xr.Dataset({"theta": (("chain", "draw", "dim"), np.swapaxes(draws, 0, 1))})
        return bool(
            float(az.rhat(ds)["theta"].max()) < R_HAT_MAX and float(az.ess(ds, method="bulk")["theta"].min()) > ESS_MIN
        )

    # a thinned copy first (every k-th step, k ≤ τ_max/10 keeps R-hat and the bulk ESS), the whole chain to confirm
    k = int(min(len(kept) // CHECK_STEPS, np.max(tau) // CHECK_STEPS_PER_TAU))
    return (k <= 1 or passes(kept[::k])) and passes(kept)


class _DeferredInterrupt:
    """While sampling in the main thread, a first Ctrl-C (SIGINT) only asks the chain to stop after the current step
    (the checkpoint is then flushed and KeyboardInterrupt raised outside emcee, which would print the walkers and a
    traceback of an error raised inside the log-density); a second one interrupts at once."""

    def __init__(self):
        self.requested = False
        self._old = None

    def _handler(self, signum, frame):
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            self._old = signal.signal(signal.SIGINT, self._handler)
        return self

    def __exit__(self, *exc):
        if self._old is not None:
            signal.signal(signal.SIGINT, self._old)
            self._old = None
        return False


def sample(
    logp,
    start,
    chain_path,
    *,
    walkers: int,
    ndim: int,
    seed: int,
    steps: int,
    resume: bool = False,
    budget_s: float | None = None,
    min_steps: int = 0,
    progress: bool = True,
    moves=None,
    t0: float | None = None,
    stop_when_converged: bool = False,
    check_every: int | None = None,
    flush_s: float = 1.0,
    adapt: bool = False,
    proposal=None,
    monitor=None,
) -> Chain:
    """Run (or continue) an emcee ensemble with an HDF5 checkpoint.

    Parameters
    ----------
    logp : callable
        ``(W, D) -> (W,)`` log-posterior, vectorised over walkers.
    start : (W, D) float, or a callable returning it
        Initial ensemble; a callable is called only when a new chain starts (not on resume).
    walkers, ndim : int
        Ensemble size W and dimension D; a resumed chain must have the same.
    chain_path : path or None
        emcee HDF5 backend, written in batches at most every ``flush_s`` seconds (a killed run loses at most that
        much sampling). None samples in memory (no checkpoint, no resume).
    seed : int
        Seeds emcee's random state (checked to have taken effect).
    steps : int
        Total chain length (the most, with ``stop_when_converged``); a resumed chain continues up to it.
    resume : bool
        Continue the chain in ``chain_path`` when it holds one (else start a new chain).
    budget_s : float, seconds, optional
        Stop sampling once this much wall-clock time has passed since ``t0``.
    min_steps : int
        The budget stops the chain only once it holds this many steps: a run whose preparation (e.g. a tempered
        SMC on a slow or busy machine) took the whole budget still returns a chain to summarise, marked as stopped
        by the budget.
    moves : emcee moves, optional
        Default :func:`default_moves`.
    t0 : float, optional
        ``time.perf_counter()`` at the start of the whole run (default: now).
    stop_when_converged : bool
        At checks spaced by ``max(check_every, 0.1 × length)`` steps (:data:`CHECK_GROWTH`; a check reads the whole
        chain, so a fixed spacing makes long runs quadratic in their length), stop once the draws kept after burn-in
        span more than 50 integrated autocorrelation times (:func:`_tau_and_burn`), the estimate
        of the largest τ moved less than 5 % since the last check and R-hat and the bulk ESS of the sampled
        parameters (or of ``monitor``'s quantities) pass (:func:`_looks_converged`).
    check_every : int, optional
        Fewest steps between convergence checks (default 50 for an adaptive run, 250 otherwise).
    flush_s : float, seconds
        Checkpoint interval.
    adapt : bool
        Sample with :func:`adaptive_moves` (unless ``moves`` are given, which must then hold an
        :class:`IndependenceT`; an :class:`IndependenceMixture` is in force from step 0, and refitted only when it
        is ``adaptive``): at steps 100, 200, 400, … (:func:`adaptation_steps`) the independence proposal is
        refitted to the draws of the second half of the chain before that step (an adaptive mixture by
        :meth:`IndependenceMixture.refit`, seeded by ``(seed, step)``). Each stage's kernel leaves the
        target invariant and the kernel changes finitely often, so the chain's law converges to the target as a
        fixed kernel's would; the proposal at every step is a function of the stored chain, so a resumed run uses
        the kernel the uninterrupted run would have. τ and burn-in are taken after the first adaptation
        (:func:`_tau_and_burn`).
    proposal : (mean (D,), cov (D, D)), optional
        An adaptive run's first independence proposal, in force from step 0 (e.g. the Laplace approximation the
        start ensemble was drawn from; it must be the same on resume). Each refit then replaces the proposal in
        force only when its log importance weights over the refit's draws spread less
        (:meth:`IndependenceT.weight_spread`), and τ and burn-in are taken from step 0.
    monitor : callable, optional
        ``(N, D) -> (N, Q)``: the quantities the run will be judged on (e.g. the canonicalised natural parameters
        of the summary), whose τ, R-hat and ESS the stopping rule then checks instead of the sampled parameters',
        so a run does not stop early on a criterion its summary then fails; the returned τ and burn-in are theirs
        too (sampled coordinates that wander between aliases of one surface, such as periodic angles, would
        otherwise make τ meaningless).
    """
    if not callable(logp):
        raise BadInput(
            f"logp: expected a callable (W, D) -> (W,) log-density, got {type(logp).__name__} {shown(logp, 60)}"
        )
    check_int(walkers, "walkers", 2, None, "an integer number of walkers")
    check_int(ndim, "ndim", 1, None, "an integer number of parameters")
    check_int(steps, "steps", 1, None, "an integer number of steps")
    check_seed(seed)
    if chain_path is not None:
        check_path(chain_path, "chain_path")
    t0 = time.perf_counter() if t0 is None else t0
    if chain_path is None:  # in memory: short runs for which a checkpoint costs more than it saves
        backend = emcee.backends.Backend()
        resume = False
    else:
        chain_path = Path(chain_path)
        backend = _buffered_hdf_backend(chain_path, flush_s)
    if resume and chain_path.exists():
        try:
            done = backend.iteration
        except (OSError, KeyError) as e:  # a file that is not an emcee chain, or one damaged mid-write
            raise BadInput(
                f"--resume: {chain_path} cannot be read as an emcee chain ({type(e).__name__}); "
                "pass --overwrite to start the run again (its files are set aside), or choose another folder"
            ) from None
    if resume and chain_path.exists() and done > 0:
        if tuple(backend.shape) != (walkers, ndim):
            raise BadInput(
                f"--resume: {chain_path} has {backend.shape[0]} walkers × {backend.shape[1]} parameters, "
                f"not {walkers} × {ndim}"
            )
        start = None
    else:
        start = start() if callable(start) else start
        start = as_array(start, "start", (walkers, ndim), f"a ({walkers}, {ndim}) ensemble (walkers × parameters)")
        backend.reset(walkers, ndim)
    flush = getattr(backend, "flush", lambda: None)
    moves = moves or (adaptive_moves() if adapt else default_moves())
    indep = next((m for m, _ in moves if isinstance(m, IndependenceT)), None) if adapt else None
    if adapt and indep is None:
        raise ValueError("adapt=True needs an IndependenceT among the moves")
    check_every = (50 if adapt else 250) if check_every is None else int(check_every)
    mixture = isinstance(indep, IndependenceMixture)

    def adapt_to(a: int, lp, chain) -> None:
        """Adaptation step ``a``: fit the draws of the second half of the chain before it, when they look stationary
        (:func:`_stationary`). Without a given ``proposal`` the fit is put in force (none yet: the move stays
        differential evolution); with one, or for an adaptive mixture, it replaces the proposal in force only when
        its log weights over those draws spread less."""
        if not _stationary(lp[a // 2 : a]):
            return
        x, lx = chain[a // 2 : a].reshape(-1, ndim), lp[a // 2 : a].ravel()
        if mixture:
            indep.refit(x, lx, np.random.default_rng([seed, a]))
        elif proposal is None:
            indep.fit(x)
        else:
            cand = IndependenceT(None, indep.nu)
            cand.fit(x)
            if cand.weight_spread(x, lx) < indep.weight_spread(x, lx):
                indep.fit(x)

    def replay(upto: int) -> None:
        """Set the independence proposal as the uninterrupted run had it after step ``upto``: from the proposal it
        started with, the adaptation steps ≤ ``upto`` in order (a resumed run; a running one adapts step by
        step)."""
        if proposal is not None:
            indep.set(*proposal)
        if mixture:
            indep.reset()
        steps_ = adaptation_steps(upto)
        if steps_:
            lp, chain = backend.get_log_prob(), backend.get_chain()
            for a in steps_:
                adapt_to(a, lp, chain)

    if proposal is not None and indep is None:
        raise ValueError("a proposal needs adapt=True")
    # where the kept draws' kernel begins: the first adaptation, or step 0 when a proposal or a mixture is given
    skip_to = 0 if proposal is not None or mixture else ADAPT_FIRST
    if indep is not None:
        replay(backend.iteration)

    def halves(thetas):
        """The whole ensemble (emcee's first evaluation, whole-ensemble moves) in the red-blue moves' half batches,
        so a jitted log-density compiles one batch size."""
        if len(thetas) != walkers or walkers < 2:
            return logp(thetas)
        h = walkers // 2
        return np.concatenate([np.asarray(logp(thetas[:h])), np.asarray(logp(thetas[h:]))])

    sampler = emcee.EnsembleSampler(walkers, ndim, halves, vectorize=True, backend=backend, moves=moves)
    # A new chain starts from the stream of (seed, 0). A resumed one continues from the random state saved with
    # the checkpoint's last sample (emcee's sample(State) sets it, replacing the one set here), so it proceeds
    # exactly as the uninterrupted run would from that step; a changed seed is refused before (run.json).
    state = np.random.RandomState([seed, backend.iteration]).get_state()
    sampler.random_state = state
    if not np.array_equal(sampler.random_state[1], state[1]):
        raise RuntimeError("emcee did not take the random state")
    first = backend.iteration
    todo = steps - first
    stopped = False
    old_tau = None
    adapt_at = set(adaptation_steps(steps)) if indep is not None else set()
    # the check lengths are one fixed sequence (check_every, then _next_check of each), so a resumed run checks where
    # the uninterrupted one did
    next_check = check_every
    while next_check <= first:
        next_check = _next_check(next_check, check_every)
    seen = _MonitoredChain(monitor)
    if todo > 0:
        with _DeferredInterrupt() as interrupt:
            try:
                for i, _ in enumerate(
                    sampler.sample(
                        start if start is not None else backend.get_last_sample(), iterations=todo, progress=progress
                    ),
                    start=1,
                ):
                    if budget_s is not None and time.perf_counter() - t0 > budget_s and first + i >= min_steps:
                        stopped = True
                        break
                    if first + i in adapt_at:
                        flush()
                        adapt_to(first + i, backend.get_log_prob(), backend.get_chain())
                    if stop_when_converged and first + i >= next_check:
                        next_check = _next_check(first + i, check_every)
                        flush()
                        chain = seen.extend(backend.get_chain())
                        lp_now = backend.get_log_prob()
                        tau, burn, length = _tau_and_burn(chain, adapt, skip_to, thin=True, log_prob=lp_now)
                        if old_tau is not None and _looks_converged(chain, tau, old_tau, burn, length):
                            break
                        old_tau = tau
                    if interrupt.requested:
                        break
            finally:
                flush()
        if interrupt.requested:  # after the checkpoint is flushed, outside emcee (which prints a raised error)
            raise KeyboardInterrupt
    chain = backend.get_chain()
    lp = backend.get_log_prob()
    n_done = chain.shape[0]
    tau, burn, length = _tau_and_burn(seen.extend(chain), adapt, skip_to, log_prob=lp)
    tau_max = float(np.nanmax(tau)) if np.isfinite(tau).any() else float("nan")
    acc = float(np.mean(sampler.acceptance_fraction)) if todo > 0 and sampler.iteration > 0 else None
    return Chain(
        chain[burn:],
        lp[burn:],
        int(n_done),
        burn,
        tau_max,
        acc,
        stopped,
        time.perf_counter() - t0,
        length if length != n_done else None,
    )


def convergence(r_hat, ess_bulk, chain: Chain, names=None) -> dict:
    """Diagnostics of a run: converged only when every R-hat < 1.01, every bulk ESS > 400 and the stretch τ was
    estimated on (the kept draws) is longer than 50 autocorrelation times (never claimed otherwise).

    ``r_hat``, ``ess_bulk`` (Q,), ``chain`` and ``names`` are those of :func:`not_converged_because`.

    Returns
    -------
    dict
        ``converged``, ``max_r_hat``, ``min_ess_bulk``, ``n_samples``, ``steps``, ``burn_in``, ``walkers``,
        ``autocorr_time_max`` (steps), ``acceptance``, ``stopped_by_budget``, and ``not_converged_because``
        (:func:`not_converged_because`: one sentence per failed check, empty when converged).
    """
    # the checks live in not_converged_because: converged is "no check failed"
    why = not_converged_because(r_hat, ess_bulk, chain, names)
    return {
        "converged": not why,
        "max_r_hat": float(np.max(r_hat)),
        "min_ess_bulk": float(np.min(ess_bulk)),
        "n_samples": int(chain.kept.shape[0] * chain.kept.shape[1]),
        "steps": chain.steps,
        "burn_in": chain.burn,
        "walkers": int(chain.kept.shape[1]),
        "autocorr_time_max": chain.tau_max,
        "acceptance": chain.acceptance,
        "stopped_by_budget": chain.stopped_by_budget,
        "not_converged_because": why,
    }


def not_converged_because(r_hat, ess_bulk, chain: Chain, names=None, shown: int = 3) -> list[str]:
    """Why a run's chain fails :func:`convergence`'s checks: one sentence per failed check, naming the worst
    quantities (at most ``shown`` each), how much longer the chain would need to be and how to continue it.

    Parameters
    ----------
    r_hat, ess_bulk : (Q,) float
        R-hat and bulk ESS of the judged quantities.
    chain : Chain
    names : sequence of str, optional
        The quantities' names (Q,); default ``q0``, ``q1``, …
    shown : int
        Most quantities named per check.

    Returns
    -------
    list of str
        Empty when every check passes.
    """
    r = np.asarray(r_hat, float)
    e = np.asarray(ess_bulk, float)
    names = [f"q{i}" for i in range(len(r))] if names is None else [str(n) for n in names]
    if len(names) != len(r) or len(e) != len(r):
        raise ValueError(f"not_converged_because: {len(r)} R-hats, {len(e)} ESS values and {len(names)} names")
    out = []
    # NaN R-hat or ESS (a quantity that never moved) fails too, and is named first
    bad_r = np.flatnonzero(~(r < R_HAT_MAX))
    if bad_r.size:
        worst = bad_r[np.argsort(-np.nan_to_num(r[bad_r], nan=np.inf))][:shown]
        listed = ", ".join(f"{names[i]} {r[i]:.3f}" for i in worst)
        out.append(
            f"R-hat ≥ {R_HAT_MAX:g} for {bad_r.size} quantit{'y' if bad_r.size == 1 else 'ies'} ({listed}): "
            "the walkers have not yet agreed on the distribution"
        )
    bad_e = np.flatnonzero(~(e > ESS_MIN))
    if bad_e.size:
        worst = bad_e[np.argsort(np.nan_to_num(e[bad_e], nan=-np.inf))][:shown]
        listed = ", ".join(f"{names[i]} {e[i]:.0f}" for i in worst)
        out.append(
            f"bulk ESS at most {ESS_MIN:.0f} for {bad_e.size} quantit{'y' if bad_e.size == 1 else 'ies'} ({listed})"
        )
    length = chain.steps if chain.tau_steps is None else chain.tau_steps
    tau = float(chain.tau_max)
    if not np.isfinite(tau):
        out.append(f"the autocorrelation time could not be estimated from {length} steps: the chain is too short")
    elif not length > TAU_FACTOR * tau:
        need = int(np.ceil(TAU_FACTOR * tau - length)) + 1
        out.append(
            f"the kept chain is {length} steps, {length / tau:.0f} autocorrelation times of τ = {tau:.0f} steps "
            f"(needs {TAU_FACTOR:.0f}): about {need} more steps"
        )
    if out:
        out.append(
            "the time budget stopped the chain: continue it with --resume (resume=True) and a larger --budget"
            if chain.stopped_by_budget
            else "the chain reached its step limit: continue it with --resume (resume=True) and a larger --steps"
        )
    return out
