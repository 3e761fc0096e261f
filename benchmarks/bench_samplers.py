"""A fair sampler comparison on the contact-level posterior: emcee (the project's adaptive moves) against NUTS in
numpyro and in blackjax, on the same log-density, the same data and the same start, every contestant compiled and
warmed before it is timed, and every one judged by the same ESS estimator.

Posteriors (:func:`posteriors`; the Student-t contact likelihood of :func:`bayestouch.inference.contact.make_log_prob`
with ``models/priors.toml``'s ν and priors, 11 parameters):

* ``covered``: 1000 contacts all round a tilted n-ellipsoid (semi-axes 30/22/15 mm, n = 2.2, 0.3 mm noise) — the
  near-Gaussian case;
* ``sparse``: a one-sided set of :mod:`benchmarks.bench_user_sets` (its generator, :data:`SPARSE_SEED`, no
  displaced contacts, strokes within a 110° cap) — ridges along the unseen directions;
* ``displaced``: a set of the same generator with 15 % of the contacts displaced 3–10 mm along the normal
  (:data:`DISPLACED_SEED`) — heavy tails.

Contestants, each from the same start (the evolutionary-search optimum :func:`bayestouch.inference.run.initial_theta`;
every NUTS chain and every emcee walker jittered around it by the same small ball, :func:`bayestouch.inference.run.
start_ball`):

* **bayestouch default** (``run_contact_fit(init="auto")`` with this benchmark's Student-t likelihood): for the
  covered set the optimum's ball and the adaptive t proposal, for the others the tempered SMC from the prior, the
  optimum check and emcee with the adaptive independence mixture; the whole run timed with its outputs (a first
  run on the same data compiles it);
* **emcee**, 32 walkers, :data:`EMCEE_STEPS` steps with ``run_contact_fit``'s adaptive moves from an optimum
  (:func:`bayestouch.inference.sampler.sample` with ``adapt=True``: a t independence proposal refitted at steps 100,
  200, 400, … plus differential evolution), the log-density in mixed precision as ``run_contact_fit`` samples it
  (float64 for the others; its error is < 3e-4 nat, ``bench_inference``), compiled for both batch sizes first;
* **numpyro NUTS**, :data:`CHAINS` chains (vectorised), dense mass matrix, :data:`WARMUP` warm-up and :data:`DRAWS`
  draws per chain, max tree depth 10 (numpyro's defaults otherwise); the MCMC object runs once with another key to
  compile, then the timed run;
* **blackjax NUTS**, the same numbers, Stan's window adaptation (``blackjax.window_adaptation``, dense mass matrix),
  each chain one jitted program (warm-up and draws) compiled by a first call before the timed chains.

Both NUTS run on the unconstrained coordinates of :mod:`bayestouch.inference.nuts` (the prior box mapped through a
logistic, its Jacobian added): the same posterior over θ.

ESS (one estimator for all, ArviZ's rank-normalised bulk and tail ESS, Vehtari et al. 2021) of the quantities the
project's summaries judge: the canonical semi-axes a ≥ b ≥ c, n, σ and the volume (alias-invariant: the angles and
unordered axes are not). emcee's walkers are its chains there, as everywhere in the project (they are not
independent: the ensemble moves couple them, which ArviZ's ESS does not see; the R-hat of those same "chains" is
reported with it). Per contestant: the smallest bulk and tail ESS, wall time of the timed run (warm-up/adaptation
included, compilation not), ESS per second, log-density evaluations (emcee) or gradient evaluations (NUTS: leapfrog
steps, warm-up included), R-hat and divergences.

Run: ``OMP_NUM_THREADS=1 python -m benchmarks bench_samplers`` (needs the ``[nuts]`` extra: numpyro, blackjax).
"""

from __future__ import annotations

import time

import numpy as np

from bayestouch.backend import jax, jnp
from bayestouch.geometry import nellipsoid as ne
from bayestouch.inference import contact as cm
from bayestouch.inference.nuts import from_unconstrained, make_potential, to_unconstrained
from bayestouch.inference.run import initial_theta, natural_draws, start_ball
from bayestouch.inference.sbc import simulate_points

#: the covered posterior's truth (centre m, log axes, Euler angles rad, log n, log σ) and its point count
THETA = np.array([0.0, 0.0, 0.0, np.log(0.03), np.log(0.022), np.log(0.015), 0.4, 0.3, -0.5, np.log(2.2), np.log(3e-4)])
N_POINTS = 1000
#: seeds of the sparse (one-sided) and displaced-contact sets of benchmarks.bench_user_sets
SPARSE_SEED = 2
DISPLACED_SEED = 6
#: NUTS chains, warm-up and draws per chain; emcee walkers and steps
CHAINS = 4
WARMUP = 500
DRAWS = 1000
WALKERS = 32
EMCEE_STEPS = 3000
#: closed-form volumes (m³, eq. 11) of natural draws' first 10 columns
_volumes = jax.jit(jax.vmap(lambda v: ne.volume(ne.from_vector(v))))
#: quantities judged: canonical a, b, c, n, σ (columns of natural_draws) and the volume
JUDGED = ("a", "b", "c", "n", "sigma", "volume")


def posteriors() -> dict[str, np.ndarray]:
    """The three contact sets (name → (M, 3) m)."""
    from benchmarks.bench_user_sets import make_user_set

    return {
        "covered": simulate_points(THETA, N_POINTS, np.random.default_rng(0)),
        "sparse": make_user_set(SPARSE_SEED, outlier_fraction=0.0, cap_deg=110.0).points,
        "displaced": make_user_set(DISPLACED_SEED, outlier_fraction=0.15).points,
    }


def judged(theta) -> np.ndarray:
    """θ draws (..., 11) → the judged quantities (..., 6): canonical a ≥ b ≥ c (m), n, σ (m), volume (m³)."""
    th = np.asarray(theta, float)
    nat = natural_draws(th.reshape(-1, th.shape[-1]))
    vol = np.asarray(_volumes(jnp.asarray(nat[:, :10])))
    out = np.column_stack([nat[:, 3], nat[:, 4], nat[:, 5], nat[:, 9], nat[:, 10], vol])
    return out.reshape(*th.shape[:-1], len(JUDGED))


def ess_summary(draws) -> dict:
    """Smallest rank-normalised bulk and tail ESS and largest R-hat over :data:`JUDGED` of ``draws`` (chains,
    draws, 11) θ."""
    import arviz as az
    import xarray as xr

    q = judged(draws)
    ds = xr.Dataset({"q": (("chain", "draw", "quantity"), q)}, coords={"quantity": list(JUDGED)})
    bulk = az.ess(ds, method="bulk")["q"].values
    tail = az.ess(ds, method="tail")["q"].values
    rhat = az.rhat(ds)["q"].values
    return {
        "ess_bulk": float(np.min(bulk)),
        "ess_tail": float(np.min(tail)),
        "r_hat": float(np.max(rhat)),
        "worst_bulk": JUDGED[int(np.argmin(bulk))],
        "posterior_mean_volume_m3": float(np.mean(q[..., -1])),
    }


def _emcee(pts, priors, theta0, seed: int) -> dict:
    from bayestouch.inference.sampler import sample

    logp, bounds = cm.make_log_prob(pts, priors, precision="mixed")
    for w in (WALKERS, WALKERS // 2):
        logp(np.repeat(theta0[None], w, axis=0))  # compiled for both batch sizes before the timing
    start = start_ball(theta0, bounds, WALKERS, np.random.default_rng(seed))
    t = time.perf_counter()
    ch = sample(logp, start, None, walkers=WALKERS, ndim=11, seed=seed, steps=EMCEE_STEPS, progress=False, adapt=True)
    secs = time.perf_counter() - t
    return {
        "draws": np.swapaxes(ch.kept, 0, 1),
        "seconds": secs,
        "evaluations": WALKERS * EMCEE_STEPS,
        "evaluation": "log-density",
        "settings": f"{WALKERS} walkers, {EMCEE_STEPS} steps (burn-in {ch.burn}), adaptive moves, mixed precision",
        "divergences": None,
    }


def _starts(theta0, bounds, seed: int) -> np.ndarray:
    return start_ball(theta0, bounds, CHAINS, np.random.default_rng([seed, 1]))


def _numpyro(pts, priors, theta0, seed: int) -> dict:
    from numpyro.infer import MCMC, NUTS

    potential, bounds = make_potential(pts, priors)
    u0 = jnp.asarray(to_unconstrained(_starts(theta0, bounds, seed), bounds))
    mcmc = MCMC(
        NUTS(potential_fn=potential, dense_mass=True),
        num_warmup=WARMUP,
        num_samples=DRAWS,
        num_chains=CHAINS,
        chain_method="vectorized",
        progress_bar=False,
    )
    fields = ("num_steps", "diverging")
    mcmc.warmup(jax.random.PRNGKey(seed + 1000), init_params=u0, extra_fields=fields, collect_warmup=True)
    mcmc.run(mcmc.post_warmup_state.rng_key, extra_fields=fields)  # compiles both programs
    t = time.perf_counter()
    mcmc.warmup(jax.random.PRNGKey(seed), init_params=u0, extra_fields=fields, collect_warmup=True)
    warm_steps = int(np.sum(mcmc.get_extra_fields()["num_steps"]))
    mcmc.run(mcmc.post_warmup_state.rng_key, extra_fields=fields)
    u = np.asarray(mcmc.get_samples(group_by_chain=True))
    secs = time.perf_counter() - t
    extra = mcmc.get_extra_fields(group_by_chain=True)
    return {
        "draws": np.asarray(from_unconstrained(jnp.asarray(u), bounds)),
        "seconds": secs,
        "evaluations": warm_steps + int(np.sum(extra["num_steps"])),
        "evaluation": "gradient",
        "settings": f"{CHAINS} chains (vectorized), {WARMUP} warm-up + {DRAWS} draws, dense mass, max tree depth 10",
        "divergences": int(np.sum(extra["diverging"])),
    }


def _blackjax(pts, priors, theta0, seed: int) -> dict:
    import blackjax

    potential, bounds = make_potential(pts, priors)

    def logdensity(u):
        return -potential(u)

    @jax.jit
    def chain(key, u0):
        k_warm, k_draw = jax.random.split(key)
        warmup = blackjax.window_adaptation(blackjax.nuts, logdensity, is_mass_matrix_diagonal=False)
        (state, params), _ = warmup.run(k_warm, u0, num_steps=WARMUP)
        kernel = blackjax.nuts(logdensity, **params)

        def one(st, k):
            st, info = kernel.step(k, st)
            return st, (st.position, info.num_integration_steps, info.is_divergent)

        _, (pos, steps, div) = jax.lax.scan(one, state, jax.random.split(k_draw, DRAWS))
        return pos, jnp.sum(steps), jnp.sum(div)

    u0 = jnp.asarray(to_unconstrained(_starts(theta0, bounds, seed), bounds))
    jax.block_until_ready(chain(jax.random.PRNGKey(seed + 1000), u0[0]))  # compiles
    t = time.perf_counter()
    keys = jax.random.split(jax.random.PRNGKey(seed), CHAINS)
    outs = [chain(keys[c], u0[c]) for c in range(CHAINS)]
    jax.block_until_ready(outs)
    secs = time.perf_counter() - t
    u = np.stack([np.asarray(o[0]) for o in outs])
    return {
        "draws": np.asarray(from_unconstrained(jnp.asarray(u), bounds)),
        "seconds": secs,
        "evaluations": int(sum(int(o[1]) for o in outs)),
        "evaluation": "gradient (draws only: the window adaptation's steps are not reported by blackjax)",
        "settings": f"{CHAINS} chains, window adaptation {WARMUP} steps (dense) + {DRAWS} draws",
        "divergences": int(sum(int(o[2]) for o in outs)),
    }


def _default(pts, priors, theta0, seed: int) -> dict:
    """``run_contact_fit``'s default path (``init="auto"``) with this benchmark's likelihood: for data that surround
    the object the optimum's ball with the adaptive t proposal, else the tempered SMC from the prior, the optimum
    check and emcee with the SMC's adaptive independence mixture — everything timed (outputs included), a first
    run on the same data compiling it."""
    import tempfile
    from pathlib import Path

    import emcee

    from bayestouch.inference.run import run_contact_fit

    kw = {"noise": "student", "init": "auto", "steps": EMCEE_STEPS, "stop_when_converged": False, "budget_s": None}
    with tempfile.TemporaryDirectory() as tmp:
        run_contact_fit(pts, Path(tmp) / "compile", seed=seed + 1, progress=False, **kw)
        t = time.perf_counter()
        s = run_contact_fit(pts, Path(tmp) / "run", seed=seed, progress=False, **kw)
        secs = time.perf_counter() - t
        chain = emcee.backends.HDFBackend(str(Path(tmp) / "run" / "chain.h5"), read_only=True).get_chain()
    burn = int(s["diagnostics"]["burn_in"])
    smc = s["model"].get("smc")
    start = (
        "the optimum's ball"
        if smc is None
        else (f"SMC {smc['particles']} particles in {smc['stages']} stages ({smc['seconds']:.1f} s)")
    )
    return {
        "draws": np.swapaxes(chain[burn:], 0, 1),
        "seconds": secs,
        "evaluations": (0 if smc is None else int(smc["evaluations"])) + WALKERS * EMCEE_STEPS,
        "evaluation": "log-density (SMC's HMC gradients counted as evaluations; the optimum search's not counted)",
        "settings": f"run_contact_fit init='auto' ({s['model']['init']}): {start}, {WALKERS} walkers × "
        f"{EMCEE_STEPS} steps (burn-in {burn}), outputs written",
        "divergences": None,
    }


CONTESTANTS = {
    "emcee": _emcee,
    "bayestouch default": _default,
    "numpyro NUTS": _numpyro,
    "blackjax NUTS": _blackjax,
}


def bench_samplers(names=None, contestants=None) -> list[dict]:
    """ESS per second of every contestant on every posterior (module docstring); rows per (posterior, contestant)
    and the ratio of emcee's bulk ESS/s to each NUTS's."""
    priors = cm.load_priors()
    sets = posteriors()
    rows = []
    for name in names or sets:
        pts = sets[name]
        theta0 = initial_theta(pts, 0, priors)
        # the samplers' densities agree (emcee's float64 density against the NUTS potential's θ density)
        f64, bounds = cm.make_log_prob(pts, priors)
        ref = float(cm.log_prob(jnp.asarray(theta0), jnp.asarray(pts), bounds, float(priors.student_nu)))
        if abs(float(f64(theta0[None])[0]) - ref) > 1e-6 * max(1.0, abs(ref)):
            raise RuntimeError(f"{name}: the contestants' log-densities differ at the start")
        rate = {}
        for who in contestants or CONTESTANTS:
            r = CONTESTANTS[who](pts, priors, theta0, 0)
            s = ess_summary(r["draws"])
            rate[who] = s["ess_bulk"] / r["seconds"]
            rows.append(
                {
                    "metric": f"min bulk ESS per second ({name}, {who})",
                    "value": rate[who],
                    "unit": "1/s",
                    "posterior": name,
                    "points": int(len(pts)),
                    "sampler": who,
                    "min_ess_bulk": round(s["ess_bulk"], 1),
                    "min_ess_tail": round(s["ess_tail"], 1),
                    "worst_quantity": s["worst_bulk"],
                    "max_r_hat": round(s["r_hat"], 4),
                    "seconds": round(r["seconds"], 2),
                    "tail_ess_per_s": round(s["ess_tail"] / r["seconds"], 2),
                    "evaluations": r["evaluations"],
                    "evaluation": r["evaluation"],
                    "divergences": r["divergences"],
                    "settings": r["settings"],
                    "volume_mean_m3": s["posterior_mean_volume_m3"],
                    "ess_estimator": "ArviZ rank-normalised bulk/tail ESS, min over a, b, c, n, sigma, volume",
                    "timing": "compiled and warmed before timing; adaptation/warm-up included",
                }
            )
        for who in rate:
            if who.endswith("NUTS") and "emcee" in rate:
                rows.append(
                    {
                        "metric": f"emcee / {who} bulk ESS per second ({name})",
                        "value": rate["emcee"] / rate[who],
                        "unit": "1",
                        "posterior": name,
                    }
                )
    return rows
