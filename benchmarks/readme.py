"""The README's table of measured figures, rendered from the committed results in ``benchmarks/results/``.

Every number in that table is formatted here from a result file, never typed: ``make bench`` (the harness) and
``python -m benchmarks.readme`` rewrite the block between :data:`BEGIN` and :data:`END` in README.md, and
``tests/test_readme.py`` checks that the README holds exactly what the committed results render to. A row whose
result file is missing is left out (and named by :func:`missing`), so the README never quotes a figure that
cannot be checked.
"""

from __future__ import annotations

import json
import statistics
import sys
from collections.abc import Callable
from pathlib import Path

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"
README = HERE.parent / "README.md"
BEGIN = "<!-- measured:begin (rendered by benchmarks/readme.py from benchmarks/results; do not edit) -->"
END = "<!-- measured:end -->"

__all__ = ["BEGIN", "END", "ROWS", "render", "missing", "update_readme"]


def _entry(doc: dict, metric_prefix: str) -> dict:
    return next(r for r in doc["results"] if r["metric"].startswith(metric_prefix))


def _ci(c, digits: int = 2) -> str:
    return f"[{c[0]:.{digits}f}, {c[1]:.{digits}f}]"


def _pct(x: float, digits: int = 1) -> str:
    return f"{100 * x:.{digits}f} %"


def _raw(doc: dict) -> tuple[str, str, str]:
    on = _entry(
        doc, "raw-current posterior, standard scenario (egg, 10 strokes, seed 3, empirical), end to end, texture=auto"
    )
    off = _entry(
        doc, "raw-current posterior, standard scenario (egg, 10 strokes, seed 3, empirical), end to end, texture=off"
    )
    z = on["volume_rel_error"] / on["volume_rel_sd"]
    lag = on.get("lag_s")
    return (
        "Raw-current posterior, standard scenario (egg, 10 strokes), texture sampled, the finger's gains and "
        "response unknown to the fit (marginalised)" + (", the response lag sampled" if lag else ""),
        f"{on['value']:.0f} s end to end ({on['steps']} steps, R-hat {on['max_r_hat']:.3f}, min bulk ESS "
        f"{on['min_ess_bulk']:.0f}); {off['value']:.0f} s with `--texture off`. Volume "
        f"{_pct(on['volume_rel_error'], 3)} off, posterior sd {_pct(on['volume_rel_sd'], 3)} (z {z:.1f})"
        + (f"; lag {lag[0] * 1e3:.1f} ± {lag[1] * 1e3:.1f} ms (the finger's {lag[2] * 1e3:.0f})" if lag else ""),
        "`bench_raw` (`benchmarks/results/bench_raw.json`)",
    )


def _of(q: dict) -> str:
    """'k/n [lo, hi]' of a coverage entry of ``mismatch.json``."""
    return f"{q['covered']}/{q['of']} {_ci(q['coverage_wilson95'])}"


def _mismatch(d: dict) -> tuple[str, str, str]:
    n, v = d["scenarios"], d["volume"]
    return (
        f"Raw-current posteriors when the finger is not the simulator ({n} fingers with S_p, lag, fixed-pattern "
        "spread, 1/f and drift drawn within their stated uncertainty; calibrated from 6 strokes over the sphere at "
        "3 depths; the textured egg from 10 strokes; the response lag sampled by the fit)",
        f"90 % volume intervals hold the truth in {v['covered']}/{n} {_ci(v['coverage_wilson95'])} (median \\|z\\| "
        f"{v['median_abs_z']:.1f}); wavelength {_of(d['wavelength'])}, amplitude {_of(d['amplitude'])}, "
        f"orientation {_of(d['orientation'])}"
        + (f", the finger's lag {_of(d['lag'])}" if "lag" in d else "")
        + f"; {d['converged']}/{n} converged; fit {d['fit_seconds_median']:.0f} s median (two fits at a time"
        + (f"; {d['timing_note']}" if d.get("timing_note") else "")
        + f"), calibration {d['calibration_seconds_median']:.1f} s",
        "`bench_mismatch` (`benchmarks/results/mismatch.json`)",
    )


def _user_sets_errors(b: dict) -> tuple[str, str]:
    """'median volume error … %' and 'Chamfer …' of a ``user_sets*.json`` method entry, with their intervals."""
    vci = [100 * c for c in b["volume_error"]["ci95"]]
    return (
        f"median volume error {_pct(b['volume_error']['median'])} {_ci(vci, 1)} %",
        f"Chamfer {b['chamfer_ratio']['median']:.3f} of the mean semi-axis {_ci(b['chamfer_ratio']['ci95'], 3)}",
    )


def _user_sets_coverage(b: dict) -> str:
    """The volume and semi-axis interval coverage of bayestouch's ``user_sets*.json`` entry."""
    vc, ac = b["volume_coverage_90"], b["axis_interval_coverage_90"]
    return (
        f"90 % volume intervals hold the truth in {vc['k']}/{vc['n']} {_ci(vc['wilson95'])}, semi-axis intervals "
        f"{ac['k']}/{ac['n']} {_ci(ac['wilson95'])}"
    )


def _user_sets(d: dict) -> tuple[str, str, str]:
    b, s, g = d["bayestouch"], d["sage"], d["gpis"]
    vol, chamfer = _user_sets_errors(b)
    return (
        f"Users'-like touch data ({d['sets']} sets: n 2–6, axes 12–40 mm, random rotations, 61–100 contacts on 4–6 "
        "strokes within caps of 100–180°, 0–15 % contacts displaced 3–10 mm in or out, free-space positions; "
        "default fit, 60 s budget)",
        f"{vol} (95 % bootstrap CI), {chamfer}; sage-superquadric {_pct(s['volume_error']['median'], 0)}, "
        f"{s['chamfer_ratio']['median']:.2f}; thin-plate GPIS {_pct(g['volume_error']['median'], 0)}, "
        f"{g['chamfer_ratio']['median']:.2f}. {_user_sets_coverage(b)}; "
        f"{b['off_by_more_than_3_sd']}/{b['sets']} off by more than 3 sds; {b['converged']}/{b['sets']} converged "
        f"(the others say so). Median {b['seconds']['median']:.0f} s a set, 95th percentile "
        f"{b['seconds']['p95']:.0f} s (sage {s['seconds']['median']:.2f} s, GPIS {g['seconds']['median']:.2f} s in the "
        "same run: the machine's speed varies between runs)",
        "`bench_user_sets` (`benchmarks/results/user_sets.json`)",
    )


def _user_sets_sized(d: dict) -> tuple[str, str, str]:
    b = d["bayestouch"]
    lo, hi = d["size_prior_m"]
    return (
        f"The same users'-like sets with the size prior stated (`--size-prior {lo:g}:{hi:g}`, objects "
        f"{100 * lo:.0f}–{100 * hi:.0f} cm across; the default is 1–30 cm)",
        ", ".join(_user_sets_errors(b)) + f"; {_user_sets_coverage(b)}; volume z-scores mean "
        f"{b['volume_z']['mean']:.2f}, sd "
        f"{b['volume_z']['sd']:.2f}; {b['off_by_more_than_3_sd']}/{b['sets']} off by more than 3 sds; "
        f"{b['converged']}/{b['sets']} converged. Median {b['seconds']['median']:.0f} s a set",
        "`bench_user_sets_sized` (`benchmarks/results/user_sets_sized.json`)",
    )


def _user_cli(d: dict) -> tuple[str, str, str]:
    w = d["wall_s"]
    return (
        f"Time to a posterior from a fresh command line on the same users'-like sets (`bayestouch fit CSV`, "
        f"{d['sets']} sets one after another on the otherwise idle 2-core machine, JAX compilation cache shared, "
        "empty at the start)",
        f"median {w['median']:.1f} s {_ci(w['ci95'], 1)} (95 % bootstrap CI), 95th percentile {w['p95']:.0f} s "
        f"(target: median ≤ {d['targets']['median_s']:.0f} s, 95th percentile ≤ {d['targets']['p95_s']:.0f} s); the "
        f"first run, compiling, {w['first']:.0f} s; the process's wall time, interpreter start, imports and every "
        f"output included (the fit itself: median {d['fit_s_median']:.1f} s). {d['converged']}/{d['sets']} converged "
        f"(median {d['converged_wall_s_median']:.1f} s); 90 % volume intervals hold the truth in "
        f"{d['volume_covered']}/{d['sets'] - d['failed']} {_ci(d['volume_coverage_wilson95'])}",
        "`bench_user_cli` (`benchmarks/results/user_cli.json`)",
    )


def _sbc_users(d: dict) -> tuple[str, str, str]:
    r, sq = d["rank"], d["rank_squeeze"]
    cov = r["coverage_90"]
    lo, hi = r["coverage_band95"]
    bad = [q for q, p in r["chi2_p"].items() if p < 0.01]
    beyond = d["truth_beyond_every_draw"]
    outside = [q for q, c in cov.items() if not lo <= c <= hi]
    centre = [cov[q] for q in ("x_G", "y_G", "z_G")]
    verdict = "**Not calibrated.**" if bad or outside else "Calibrated to the benchmark's power."
    return (
        f"Calibration where users are: SBC over {d['sets']} sets drawn from the fit's own prior (objects 2–10 cm, "
        "n 1.2–16, σ 1 µm–1 cm, up to 25 % contacts displaced each way), 40–120 contacts on 4–6 strokes within caps "
        "of 100–180°, default fit from the prior, 60 s budget",
        f"90 % intervals hold the truth for volume {cov['volume']:.2f}, semi-axes {cov['a_1']:.2f}/{cov['a_2']:.2f}/"
        f"{cov['a_3']:.2f}, n {cov['n']:.2f}, σ {cov['sigma']:.2f}, centre {min(centre):.2f}–{max(centre):.2f} "
        f"(calibrated: {r['coverage_expected']:.2f}, 95 % of benchmarks within "
        f"{lo:.2f}–{hi:.2f}); rank uniformity rejected (χ² p < 0.01) for {len(bad)} of {len(cov)} quantities; the "
        f"30 %-too-narrow control {sq['coverage_90']['volume']:.2f} (volume). {verdict} "
        f"{d['converged']}/{d['sets']} converged; of {beyond['sets']} sets with the truth beyond every draw of a "
        f"shape quantity, {beyond['flagged']} said so (not converged, multimodal or misfit)"
        + (f"; {d['failed']} fits failed (no posterior)" if d.get("failed") else "")
        + _noise_bands(d),
        "`bench_sbc_users` (`benchmarks/results/sbc_users.json`, `docs/img/sbc_users_ecdf.png`)",
    )


def _noise_bands(d: dict) -> str:
    """The SBC's split by σ over the smallest semi-axis, where the benchmark has it (``by_noise_ratio``)."""
    if "by_noise_ratio" not in d:
        return ""
    b = d["by_noise_ratio"]["bands"]
    low, high = b[0], b[-1]
    return (
        f". By noise over the smallest semi-axis: below {100 * low['ratio'][1]:g} % ({low['sets']} sets) volume "
        f"coverage {low['coverage_90_volume']:.2f}, and the truth sits in its own local mode as the model predicts "
        f"(rejected at 5 % in {100 * low['local_gap_rejected_5pct']:.0f} % of sets): its misses are other modes, "
        f"which the posterior prefers or the sampler missed; above {100 * high['ratio'][0]:g} % ({high['sets']} sets) "
        f"coverage {high['coverage_90_volume']:.2f} and the local check rejects the truth in "
        f"{100 * high['local_gap_rejected_5pct']:.0f} %: the first-order distance likelihood no longer describes 3-D "
        "contact noise"
    )


def _objects(d: dict) -> tuple[str, str, str]:
    b, p, s, g = d["bayestouch"], d["bayestouch-parts"], d["sage"], d["gpis"]

    def ch(m):
        return f"{m['chamfer_ratio']['median']:.3f} {_ci(m['chamfer_ratio']['ci95'], 3)}"

    def cov(m):
        c = m["volume_coverage_90"]
        return f"{c['k']}/{c['n']} {_ci(c['wilson95'])}"

    best = min(s["chamfer_ratio"]["median"], g["chamfer_ratio"]["median"])
    chosen = ", ".join(f"K = {k}: {n}" for k, n in p["parts_chosen"].items() if n)
    return (
        f"Objects that are not one superquadric ({d['sets']} sets, 8 kinds: CSG unions and differences, a mug with "
        "a handle, bent and tapered superquadrics; touched like the users'-like sets, 4–8 strokes)",
        f"median Chamfer / object size: default fit {ch(b)}, parts fit (`--parts auto`) {ch(p)}, sage-superquadric "
        f"{ch(s)}, GPIS {ch(g)} (target ≤ 0.8 × the better peer: {0.8 * best:.3f}). 90 % volume intervals hold the "
        f"truth in {cov(b)} (default) and {cov(p)} (parts; {chosen}); converged {b['converged']}/{b['sets']} and "
        f"{p['converged']}/{p['sets']}. Median {b['seconds']['median']:.0f} s (default) and "
        f"{p['seconds']['median']:.0f} s (parts) a set, one set at a time on a shared 2-core machine",
        "`bench_objects` (`benchmarks/results/objects.json`)",
    )


def _pose(d: dict) -> tuple[str, str, str]:
    def mm(key):
        m = d[key]
        return f"{m['median']:.2f} mm {_ci(m['ci95'], 2)}"

    return (
        f"Where the pad is against where a host thinks it is ({d['scenarios']} drawn fingers and wire-current "
        "programs through the bending chain: SMA thermal model, Brinson hysteresis, three-wire bend)",
        f"median tip error over frames: host with the nominal constants and the hysteresis {mm('nominal_median_mm')}"
        f" (95th percentile {mm('nominal_p95_mm')}); without the hysteresis {mm('nominal_no_hysteresis_median_mm')}"
        f"; every constant exact, no hysteresis {mm('true_no_hysteresis_median_mm')}; tip deflections up to "
        f"{d['max_deflection_mm']['median']:.1f} mm. The law of such errors, from fingers run through the "
        "commanded programs, enters `bench_pose_fit`'s last two fits and, for the guarded strokes' held currents, "
        "the exploration loop (`bench_explore_bend`); the virtual finger runs the chain for carrier strokes and with "
        "`--bend-spread`, `simulate` does not yet",
        "`bench_pose` (`benchmarks/results/pose.json`)",
    )


def _pose_fit_verdict(d: dict) -> str:
    """Which of bench_pose_fit's fits cover within the target band 85–95 %."""
    names = {
        "ignoring": "ignoring",
        "marginalised": "per-stroke offsets",
        "programs": "the programs' law",
        "offset": "the programs' law with an offset",
    }
    ok = [
        label
        for key, label in names.items()
        if key in d and 0.85 <= d[key]["volume_coverage_90"]["k"] / d[key]["volume_coverage_90"]["n"] <= 0.95
    ]
    return f"Within the target 85–95 %: {', '.join(ok)}" if ok else "None is calibrated yet (target 85–95 %)"


def _offset_arm(m: dict, arm) -> str:
    """bench_pose_fit's law with the per-stroke offset, and its coverage on the scenarios held out of the choice."""
    late = m["volume_coverage_90_held_out"]
    return (
        f"; the same law and one more offset per stroke (sd 1 mm, chosen on scenarios 0–{late['from_scenario'] - 1}"
        f"): {arm(m)} (scenarios {late['from_scenario']} on: {late['k']}/{late['n']})"
    )


def _pose_fit(d: dict) -> tuple[str, str, str]:
    def arm(m):
        c = m["volume_coverage_90"]
        return (
            f"90 % volume intervals hold the truth in {c['k']}/{c['n']} {_ci(c['wilson95'])}, median \\|z\\| "
            f"{m['abs_z_median']['median']:.2f}, median width {_pct(m['width_rel_median']['median'], 0)} of the "
            f"volume, converged {m['converged']}/{c['n']}"
            + (
                f", {m['width_over_known_median']['median']:.1f}× as wide as with the pose known"
                if "width_over_known_median" in m
                else ""
            )
        )

    return (
        f"Shape from contacts the host placed with its own idea of the pad's pose ({d['scenarios']} drawn objects "
        f"and fingers, 6 strokes × 20 contacts, pose errors from the bending chain, median "
        f"{d['pose_error_median_mm']:.1f} mm)",
        (f"the pose known exactly (reference): {arm(d['known'])}; " if "known" in d else "")
        + f"ignoring the pose error: {arm(d['ignoring'])}; one pose offset per stroke marginalised (prior median "
        f"1 mm): {arm(d['marginalised'])}; the pose error's law from {d['ensemble_draws']} fingers run through the "
        f"commanded programs (the true finger {d['truth_spread_factor']:g}× further from nominal than the host "
        f"assumes): {arm(d['programs'])}"
        + (_offset_arm(d["offset"], arm) if "offset" in d else "")
        + f". {_pose_fit_verdict(d)}",
        "`bench_pose_fit` (`benchmarks/results/pose_fit.json`)",
    )


def _explore_bend(d: dict) -> tuple[str, str, str]:
    def label(c: dict) -> str:
        spread = c.get("bend_spread", 0.0)
        draws = c.get("pose_draws", 0)
        who = "the models' constants" if not spread else f"constants drawn at {spread:g}× their spread"
        how = "encoder noise only" if not draws else f"the pose-error law of {draws} drawn fingers"
        return f"{who}, {how}" + (", calibrated on a sphere first" if c.get("bend_calibration") else "")

    def cond(c: dict) -> str:
        z = [abs(t["volume_z"]) for t in c["per_trial"]]
        ratio = c.get("volume_sd_over_reference")
        wide = (
            f", volume sd {ratio['median']:.2f}× the reference's [{ratio['lo']:.2f}, {ratio['hi']:.2f}]"
            if ratio and (c.get("bend_spread") or c.get("pose_draws"))
            else ""
        )
        return (
            f"{label(c)}: Chamfer {c['chamfer']['median']:.4f} [{c['chamfer']['lo']:.4f}, {c['chamfer']['hi']:.4f}], "
            f"volume error {_pct(c['volume_error']['median'], 2)} [{_pct(c['volume_error']['lo'], 2)}, "
            f"{_pct(c['volume_error']['hi'], 2)}], the truth within the 90 % volume interval in {c['covered']}/"
            f"{c['of']} {_ci(c['coverage_wilson95'])} (median \\|z\\| {statistics.median(z):.1f}){wide}"
        )

    conds = d["conditions"]
    return (
        f"Exploration through a finger whose bending constants are not the models' ({d['trials']} paired trials, "
        f"{d['object']}, {d['planner']}, {d['budget']} strokes after the scout; guarded strokes over the protocol, "
        "the encoder's 0.3 mm; the reference is the models' finger with the encoder noise only)",
        "; ".join(cond(c) for c in conds.values()),
        "`bench_explore_bend` (`benchmarks/results/explore_bend.json`)",
    )


def _bend_coverage(d: dict) -> tuple[str, str, str]:
    names = {
        "reference": "the models' finger (pose known to the encoders' 0.3 mm)",
        "ignoring": "a finger with its own constants, the pose error ignored",
        "calibrated": "the same finger calibrated on a sphere, its law marginalised in the loop and the fit",
    }

    def arm(name: str, a: dict) -> str:
        wide = a["width_over_reference"]
        return (
            f"{names[name]}: the truth within the 90 % volume interval in {a['volume_covered']}/{a['scenarios']} "
            f"{_ci(a['volume_coverage_wilson95'])}, semi-axes {a['axes_covered']}/{a['axes_of']} "
            f"{_ci(a['axes_coverage_wilson95'])}, {a['beyond_3sd']} beyond 3 sd (median \\|z\\| "
            f"{a['median_abs_volume_z']:.1f}), volume error {_pct(a['volume_error']['median'], 2)} "
            f"[{_pct(a['volume_error']['lo'], 2)}, {_pct(a['volume_error']['hi'], 2)}], {a['converged']} converged"
            + (
                f", interval {wide['median']:.2f}× the reference's [{wide['lo']:.2f}, {wide['hi']:.2f}]"
                if name != "reference"
                else ""
            )
        )

    return (
        f"Shape posteriors through the bending chain over {d['scenarios']} drawn objects (n-ellipsoids, semi-axes "
        f"{1e3 * d['axes_m'][0]:.0f}–{1e3 * d['axes_m'][1]:.0f} mm, n {d['n_range'][0]:g}–{d['n_range'][1]:g}, "
        f"uniform rotations; eig, {d['budget']} strokes after the scout through a virtual finger over the protocol; "
        f"the final posterior of every contact; fingers drawn at {d['bend_spread']:g}× the constants' spread)",
        "; ".join(arm(k, a) for k, a in d["arms"].items()),
        "`bench_bend_coverage` (`benchmarks/results/bend_coverage.json`)",
    )


def _explore_carrier(d: dict) -> tuple[str, str, str]:
    names = {"guarded": "guarded strokes, the law marginalised", "carrier": "carrier strokes corrected by the law"}

    def arm(name: str, a: dict) -> str:
        stops = (
            f", {a['aborted']} of {a['carrier_strokes']} carrier strokes stopped at 1 N (their frames before kept)"
            if name == "carrier"
            else ""
        )
        return (
            f"{names[name]}: Chamfer {a['chamfer']['median']:.4f} [{a['chamfer']['lo']:.4f}, {a['chamfer']['hi']:.4f}]"
            f", volume error {_pct(a['volume_error']['median'], 2)}, the truth within the 90 % volume interval in "
            f"{a['covered']}/{a['of']} {_ci(a['coverage_wilson95'])}, contacts "
            f"{1e3 * a['contact_distance_median_m']['median']:.2f} mm from the true surface (median){stops}"
        )

    return (
        f"Exploring with carrier strokes ({d['trials']} paired trials, {d['object']}, {d['planner']}, {d['budget']} "
        f"strokes after the scout; each finger drawn at {d['bend_spread']:g}× the constants' spread and calibrated on "
        "a 2-cm sphere first)",
        "; ".join(arm(k, a) for k, a in d["arms"].items()),
        "`bench_explore_carrier` (`benchmarks/results/explore_carrier.json`)",
    )


def _link_loss(doc: dict) -> tuple[str, str, str]:
    rows = [r for r in doc["results"] if r["benchmark"] == "bench_link_loss"]
    first = rows[0]

    def cell(r) -> str:
        t = r["seconds_per_stroke_median"]
        return f"{r['value'] * r['sessions']:.0f}/{r['sessions']}" + (f" ({t:.2f} s/stroke)" if t is not None else "")

    by_rate: dict[float, dict[str, dict]] = {}
    for r in rows:
        by_rate.setdefault(r["loss_per_byte"], {})[str(r["segment"])] = r
    parts = [
        f"{_pct(rate, 1)}: whole packets {cell(m['0'])}, automatic {cell(m['auto'])}" for rate, m in by_rate.items()
    ]
    return (
        f"Strokes over a link that loses bytes, both ways (virtual finger on a pty; sessions of "
        f"{first['strokes_per_session']} strokes × {first['frames_per_stroke']} frames × {first['taxels']} taxels, "
        "each delivered whole and equal to what the device produced; protocol revision 1.2 segment mode)",
        "sessions delivered whole — " + "; ".join(parts),
        "`bench_device` (`benchmarks/results/bench_device.json`)",
    )


def _sparse(doc: dict) -> tuple[str, str, str]:

    def val(metric: str, method: str) -> float:
        return next(r["value"] for r in doc["results"] if r["metric"] == metric and r.get("method") == method)

    parts = []
    for cap in (180, 100):
        vol, ch = f"median volume error (cap {cap}°)", f"median Chamfer / mean semi-axis (cap {cap}°)"
        sets = next(r["sets"] for r in doc["results"] if r["metric"] == vol)
        parts.append(
            f"strokes within a {cap}° cap ({_pct(val(f'median coverage (cap {cap}°)', 'data'), 0)} of the surface "
            f"reached, {sets} sets): median volume error {_pct(val(vol, 'bayestouch'))}, Chamfer "
            f"{val(ch, 'bayestouch'):.3f} of the mean semi-axis; sage-superquadric "
            f"{_pct(val(vol, 'sage-superquadric'))}, {val(ch, 'sage-superquadric'):.3f}"
        )
    secs = val("seconds per set (median)", "bayestouch")
    return (
        "Sparse data (35–100 points, 2–5 strokes, 0.3 mm noise, 3 of 10 sets with 15 % outliers)",
        "; ".join(parts) + f". Median {secs:.0f} s a set",
        "`bench_sparse` (`benchmarks/results/bench_sparse.json`)",
    )


def _inference(doc: dict) -> tuple[str, str, str]:
    mixed = _entry(doc, "contact log-probability evaluations/s, mixed precision")
    f64 = _entry(doc, "contact log-probability evaluations/s, float64")
    ref = _entry(doc, "reference jit(vmap)")
    err = _entry(doc, "max |log p mixed - log p float64|, 1000 points")
    return (
        "Contact-level log-probability, 1000 points, batch 64",
        f"{mixed['value']:,.0f} evaluations/s sampled (float32 powers, float64 sums; largest error "
        f"{err['value']:.1e} nat); {f64['value']:,.0f} all float64; a plain `jit(vmap)` gives {ref['value']:,.0f}",
        "`bench_inference` (`benchmarks/results/bench_inference.json`)",
    )


def _planners(doc: dict) -> tuple[str, str, str]:
    r = {e["metric"]: e for e in doc["results"]}
    parts = []
    for obj in ("egg", "box"):
        med = {p: r[f"strokes to Chamfer <= 0.005 ({obj}, {p})"] for p in ("eig", "random", "gpis")}
        ratio = {o: r[f"eig / {o} mean strokes to Chamfer <= 0.005 ({obj})"] for o in ("random", "gpis")}
        parts.append(
            f"{obj}: eig {med['eig']['value']:g}, random {med['random']['value']:g} ({med['random']['censored']} "
            f"never), gpis {med['gpis']['value']:g} strokes; eig/random {ratio['random']['value']:.2f} "
            f"{_ci(ratio['random']['ci95'])}, eig/gpis {ratio['gpis']['value']:.2f} {_ci(ratio['gpis']['ci95'])}"
        )
    n = r["strokes to Chamfer <= 0.005 (egg, eig)"]["trials"]
    box02 = r["eig / random mean strokes to Chamfer <= 0.02 (box)"]
    return (
        f"Planners through the virtual finger (guarded strokes over the protocol, pad pose error 0.3 mm; {n} paired "
        "trials per object, 8 planned strokes): median strokes to a Chamfer distance of 0.005 of the mean semi-axis",
        "; ".join(parts)
        + f". To 0.02 the egg needs only the scout whatever the planner; on the box eig/random {box02['value']:.2f} "
        f"{_ci(box02['ci95'])}. Decision per stroke: eig {r['decision time per stroke, median (eig)']['value']:.2f} s,"
        f" gpis {r['decision time per stroke, median (gpis)']['value']:.2f} s (median)",
        "`bench_planners` (`benchmarks/results/bench_planners.json`)",
    )


def _samplers(doc: dict) -> tuple[str, str, str]:
    r = {e["metric"]: e for e in doc["results"]}
    who = {
        "bayestouch default": "default",
        "emcee": "emcee alone",
        "numpyro NUTS": "numpyro",
        "blackjax NUTS": "blackjax",
    }
    parts, short = [], []
    for name in ("covered", "sparse", "displaced"):
        rows = {w: r[f"min bulk ESS per second ({name}, {w})"] for w in who}
        rates = ", ".join(f"{who[w]} {e['value']:.3g}/s (R-hat {e['max_r_hat']:.3f})" for w, e in rows.items())
        ratio = rows["bayestouch default"]["value"] / max(rows["numpyro NUTS"]["value"], rows["blackjax NUTS"]["value"])
        parts.append(f"{name} ({rows['emcee']['points']} points): {rates}; default / best NUTS {ratio:.2g}")
        if ratio < 2:
            short.append(f"{name} ({ratio:.2g}×)")
    verdict = (
        "The default reaches 2× the best NUTS on every posterior"
        if not short
        else "The default is not 2× the best NUTS on: " + ", ".join(short)
    )
    return (
        "Samplers on the same contact posterior (Student-t, 11 parameters), compiled before timing, one ESS "
        "estimator (ArviZ rank-normalised bulk ESS, min over a, b, c, n, σ, volume): the default fit path (the "
        "optimum's ball for covered data, the tempered SMC then emcee otherwise; whole run, outputs included), "
        "emcee alone from the optimum (32 walkers × 3000 steps, adaptive moves), NUTS 4 chains × (500 + 1000), "
        "dense mass",
        "min bulk ESS per second — " + "; ".join(parts) + f". {verdict}",
        "`bench_samplers` (`benchmarks/results/bench_samplers.json`)",
    )


def _texture(doc: dict) -> tuple[str, str, str]:
    def pick(prefix: str, calibrated: bool) -> dict:
        return next(
            r for r in doc["results"] if r["metric"].startswith(prefix) and ("device file" in r["metric"]) == calibrated
        )

    acc, med = pick("accuracy at decision", False), pick("median strokes to decision", False)
    cal, cal_med = pick("accuracy at decision", True), pick("median strokes to decision", True)
    return (
        "Texture identification (20 library textures, random 1 cm strokes, empirical taxel mode, a 0.5 K skin-"
        "temperature error per stroke; the identifier reads only the readings)",
        f"accuracy at decision {acc['value']:.2f} {_ci([acc['ci95_low'], acc['ci95_high']])} (Wilson) after a median "
        f"of {med['value']:.0f} stroke(s) with the gains unknown; {cal['value']:.2f} "
        f"{_ci([cal['ci95_low'], cal['ci95_high']])} after {cal_med['value']:.0f} with a device file (log-gains to "
        f"{cal['log_gain_sd_median']:.0e}). Target ≥ 0.95 within a median of 5 (Fishel & Loeb 2012)",
        "`bench_texture` (`benchmarks/results/bench_texture.json`)",
    )


def _texture_mismatch(d: dict) -> tuple[str, str, str]:
    lo, hi = d["accuracy_wilson95"]
    wlo, whi = d["wrong_decision_wilson95"]
    return (
        f"Texture identification when the finger is not the one assumed ({d['textures']} textures including 20 "
        f"close twins; {d['fingers']} fingers with S_p, lag, fixed pattern, 1/f and drift drawn within their stated "
        "uncertainty, each calibrated on 3 sphere strokes; empirical mode; one trial per texture and finger)",
        f"accuracy at decision {d['accuracy_at_decision']:.3f} {_ci([lo, hi], 3)} (Wilson, n={d['trials']}); "
        f"{d['wrong_decisions']} wrong of {d['decided']} decided at 0.95 (rate 95 % CI {_ci([wlo, whi], 3)}); "
        f"median {d['median_strokes_to_decision']:.0f} stroke(s) to decision",
        "`bench_texture_mismatch` (`benchmarks/results/texture_mismatch.json`)",
    )


def _sbc_missed(d: dict) -> tuple[str, str, str]:
    lo, hi = d["missed_wilson95"]
    gap = d["missed_gap_nats_median"]
    return (
        f"The SBC's misses at low noise: its {d['sets']} sets with the truth beyond every draw of a shape quantity at "
        f"σ below {_pct(d['noise_ratio_max'], 0)} of the smallest semi-axis, re-fitted; the truth's local mode "
        "against the fit's best draw, both climbed on the fit's log-posterior",
        f"sampler missed a mode more than {d['missed_nats']:.0f} nats above its own in {d['missed']}/{d['sets']} "
        f"[{lo:.2f}, {hi:.2f}]"
        + (f" (median {gap:.0f} nats)" if gap is not None else "")
        + f"; {d['missed_flagged']} of them flagged, {d['missed_without_any_warning']} with no warning at all",
        "`bench_sbc_missed` (`benchmarks/results/sbc_missed.json`, `docs/sbc.md`)",
    )


#: the table's rows, in order: each ``(result file, render)``; ``render`` turns the file's JSON into
#: ``(what, figure, benchmark)``
ROWS: tuple[tuple[str, Callable[[dict], tuple[str, str, str]]], ...] = (
    ("bench_inference.json", _inference),
    ("bench_raw.json", _raw),
    ("mismatch.json", _mismatch),
    ("user_sets.json", _user_sets),
    ("user_sets_sized.json", _user_sets_sized),
    ("user_cli.json", _user_cli),
    ("sbc_users.json", _sbc_users),
    ("sbc_missed.json", _sbc_missed),
    ("objects.json", _objects),
    ("pose.json", _pose),
    ("pose_fit.json", _pose_fit),
    ("explore_bend.json", _explore_bend),
    ("bend_coverage.json", _bend_coverage),
    ("explore_carrier.json", _explore_carrier),
    ("bench_sparse.json", _sparse),
    ("bench_planners.json", _planners),
    ("bench_samplers.json", _samplers),
    ("bench_device.json", _link_loss),
    ("bench_texture.json", _texture),
    ("texture_mismatch.json", _texture_mismatch),
)


def missing(results: Path = RESULTS) -> list[str]:
    """Result files a row needs that ``results`` lacks (their rows are left out of the table)."""
    return [name for name, _ in ROWS if not (results / name).is_file()]


def render(results: Path = RESULTS) -> str:
    """The block (markers included) the README must hold for the results in ``results``."""
    lines = [BEGIN, "| What | Figure | Benchmark |", "|---|---|---|"]
    for name, row in ROWS:
        if (results / name).is_file():
            lines.append("| " + " | ".join(row(json.loads((results / name).read_text()))) + " |")
    lines.append(END)
    return "\n".join(lines)


def update_readme(readme: Path = README, results: Path = RESULTS) -> bool:
    """Rewrite the measured block of ``readme`` from ``results``; returns whether the file changed."""
    text = readme.read_text(encoding="utf-8")
    if BEGIN not in text or END not in text:
        raise SystemExit(f"{readme}: no measured block ({BEGIN} … {END})")
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    new = head + render(results) + tail
    if new != text:
        readme.write_text(new, encoding="utf-8")
    return new != text


if __name__ == "__main__":
    changed = update_readme()
    print(f"README.md {'updated' if changed else 'already agrees'}; rows without results: {missing() or 'none'}")
    sys.exit(0)
