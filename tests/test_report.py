"""The HTML report: written with its figures, loaded in a real headless browser, every image rendered; and the demo
end to end at small sizes."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from bayestouch.errors import BadInput
from bayestouch.report.page import Figure, Table, check_in_browser, find_browser, write_report

# CI installs Debian's chromium (.ci/run) and sets BAYESTOUCH_REQUIRE_BROWSER=1: there a missing browser fails
NEED_BROWSER = os.environ.get("BAYESTOUCH_REQUIRE_BROWSER") == "1"
browser = pytest.mark.skipif(find_browser() is None and not NEED_BROWSER, reason="no chromium on this machine")


def _png(path, seed: int) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(2, 2))
    ax.plot(np.random.default_rng(seed).standard_normal(10))
    fig.savefig(path)
    plt.close(fig)


def _page(tmp_path, names):
    for k, n in enumerate(names):
        _png(tmp_path / n, k)
    table = Table("numbers", ["name", "value"], [["a", "1"], ["b", "2"]])
    return write_report(
        tmp_path,
        title="a test report",
        intro="<p>intro</p>",
        sections=[("figures", [Figure(n, f"figure {n}") for n in names] + [table])],
        files=["a.png", "not_there.csv"],
    )


def test_report_lists_figures_tables_and_existing_files(tmp_path):
    page = _page(tmp_path, ["a.png", "b.png"])
    text = page.read_text()
    assert text.count("<img ") == 2 and "<caption>numbers</caption>" in text
    assert 'href="a.png"' in text and "not_there.csv" not in text  # only files that exist are listed


def test_report_refuses_a_missing_figure(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing.png"):
        write_report(tmp_path, title="t", intro="", sections=[("s", [Figure("missing.png", "gone")])])


def test_report_refuses_to_replace_an_earlier_page_unless_told(tmp_path):
    first = _page(tmp_path, ["a.png"]).read_text()
    with pytest.raises(BadInput, match="report.html exists; pass overwrite=True"):
        write_report(tmp_path, title="second", intro="", sections=[])
    assert (tmp_path / "report.html").read_text() == first  # the earlier page is untouched
    write_report(tmp_path, title="second", intro="", sections=[], overwrite=True)
    assert "<title>second</title>" in (tmp_path / "report.html").read_text()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no temporary file left
    with pytest.raises(BadInput, match="overwrite"):
        write_report(tmp_path, title="t", intro="", sections=[], overwrite="no")


@browser
def test_every_image_renders_in_headless_chromium(tmp_path):
    page = _page(tmp_path, ["a.png", "b.png", "c.png"])
    seen = check_in_browser(page)
    assert (seen.images_ok, seen.images_total, seen.broken, seen.title) == (3, 3, [], "a test report")


@browser
def test_browser_check_sees_a_broken_image(tmp_path):
    # negative control: a file that is not a PNG under a .png name, and a figure deleted after writing
    page = _page(tmp_path, ["a.png", "b.png", "c.png"])
    (tmp_path / "b.png").write_bytes(b"\x89PNG but not really")
    (tmp_path / "c.png").unlink()
    seen = check_in_browser(page)
    assert (seen.images_ok, seen.images_total, sorted(seen.broken)) == (1, 3, ["b.png", "c.png"])


@pytest.mark.slow
def test_demo_end_to_end_quick(tmp_path):
    """``bayestouch demo --quick``: the run folder has every file the issue lists, the summary has the contract's
    keys, the exploration ran through a calibrated finger with the pose error marginalised, the recording reads
    back, and (with a browser) every image of report.html renders."""
    from bayestouch.cli import main
    from bayestouch.io.recording import read_recording

    out = tmp_path / "demo"
    assert main(["demo", "--quick", "--quiet", "--out", str(out), "--seed", "1"]) == 0
    for f in [
        "report.html",
        "summary.json",
        "posterior.nc",
        "mean_shape.ply",
        "uncertainty_mesh.ply",
        "chain.h5",
        "points.csv",
        "recording.nc",
        "patch_summary.json",
        "demo.json",
        "shape.png",
        "errors.png",
        "taxel_currents.png",
        "contact_patch.png",
        "trace.png",
        "pair.png",
        "strokes/summary_0.json",
    ]:
        assert (out / f).is_file(), f
    summary = json.loads((out / "summary.json").read_text())
    for name in ("a", "b", "c", "n"):
        assert set(summary["parameters"][name]) >= {"mean", "sd", "q05", "q95", "r_hat", "ess_bulk"}
    assert set(summary["diagnostics"]) >= {"converged", "max_r_hat", "min_ess_bulk", "n_samples", "seconds"}
    demo = json.loads((out / "demo.json").read_text())
    assert [r["stroke"] for r in demo["strokes"]] == [0, 1]
    # explored through a finger with its own bending constants: calibrated (its contacts closer to the sphere after
    # than with the models' constants), the pose error marginalised in the final posterior (its scale sampled)
    assert demo["prober"] == "finger"
    cal = demo["finger"]["calibration"]
    assert cal["residual_rms_calibrated_m"] < 0.6 * cal["residual_rms_nominal_m"]
    assert "pose_scale" in summary["parameters"] and "pose error" in summary["model"]["likelihood"]
    # the egg's true volume (4/3·π·abc for n = 2 is 60.8 cm³; n = 2.2 gives 66.5 cm³) within 10 % after the
    # scout and one stroke: a loose recovery check (the issue-4 tests hold the calibrated ones)
    v = summary["derived"]["volume_m3"]["mean"]
    assert 55e-6 < v < 75e-6, v
    rec = read_recording(out / "recording.nc")
    assert rec["taxel_current"].shape[1] == 256 and float(rec["contact_force"].max()) > 0
    if find_browser() is not None or NEED_BROWSER:
        seen = check_in_browser(out / "report.html")
        assert seen.images_total == 6 and seen.images_ok == 6, seen
