"""Sixth review: refusals that must come before anything of a finished run is set aside, and file-system errors
as one line."""

from pathlib import Path

from bayestouch.cli import main
from bayestouch.io.contacts import save_contact_points
from bayestouch.io.runfolder import LOCK_FILE

EGG = Path(__file__).resolve().parents[1] / "data" / "contacts" / "egg.csv"
FAST = ["--walkers", "24", "--steps", "60", "--init", "optimize", "--no-early-stop", "--budget", "0", "--quiet"]


def _run(argv) -> int:
    """The command's exit code, whether it returns it or argparse exits with it."""
    try:
        return main(argv)
    except SystemExit as e:
        return int(e.code)


def _snapshot(folder: Path) -> dict:
    """The files of ``folder`` by name (the folder's lock file, which stays with the folder, left out)."""
    return {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file() and p.name != LOCK_FILE}


def test_a_refused_recording_fit_sets_nothing_aside(tmp_path, capsys):
    """`fit RUN/posterior.nc --out RUN --overwrite` (a file that is no recording): refused in one line with exit 2
    before the finished run is moved (it was set aside, and a raw-level run.json left in its place)."""
    run = tmp_path / "run"
    assert main(["fit", str(EGG), "--out", str(run), *FAST]) == 0
    capsys.readouterr()
    before = _snapshot(run)
    assert main(["fit", str(run / "posterior.nc"), "--out", str(run), "--overwrite"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "variable 'taxel_current' is missing" in err[0]
    assert _snapshot(run) == before
    assert not any(p.name.startswith("replaced-") for p in run.iterdir())


def test_a_name_too_long_for_the_file_system_is_one_line(tmp_path, capsys):
    """A path component over 255 characters: exit 2 and one line naming the path (it was a traceback, exit 1)."""
    pts = save_contact_points(tmp_path / "p.csv", __import__("numpy").loadtxt(EGG, delimiter=",", skiprows=1)[:, :3])
    long = tmp_path / ("e" * 300)
    assert _run(["fit", str(pts), "--out", str(long), *FAST]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) <= 3 and "name too long" in err[-1].lower()  # argparse: usage line(s) and one error line
    assert _run(["fit", str(tmp_path / ("p" * 300 + ".csv")), "--out", str(tmp_path / "o"), *FAST]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "name too long" in err[0].lower()


def test_explore_overwrite_sets_every_file_of_a_fit_aside(tmp_path, capsys):
    """`explore --overwrite` into a fit's folder moved the fit's summary and chain but left its meshes and
    occupancy grid beside the new exploration: every earlier file now goes aside together."""
    run = tmp_path / "run"
    assert main(["fit", str(EGG), "--out", str(run), *FAST]) == 0
    before = _snapshot(run)
    assert {"mean_shape.ply", "occupancy.npz"} <= set(before)
    argv = ["explore", "--object", "sphere", "--strokes", "1", "--steps", "60", "--draws", "50", "--out", str(run)]
    assert main([*argv, "--overwrite"]) == 0
    (aside,) = [p for p in run.iterdir() if p.name.startswith("replaced-")]
    assert _snapshot(aside) == before
    assert not ({"mean_shape.ply", "uncertainty_mesh.ply", "occupancy.npz", "chain.h5"} & set(_snapshot(run)))


def test_currents_beyond_the_read_outs_full_scale_are_refused(tmp_path, capsys):
    """Currents × 1000 (milliamps written as amperes, 200× the ADC's 2 µA full scale) were fitted and calibrated
    without a word; both are refused naming taxel_current. The shipped recording passes (the control)."""
    import xarray as xr

    from bayestouch.inference.raw.data import load_raw_data
    from bayestouch.io.recording import write_recording

    rec = Path(__file__).resolve().parents[1] / "data" / "recordings" / "sphere.nc"
    load_raw_data(rec)
    with xr.open_dataset(rec, engine="h5netcdf") as ds:
        big = write_recording(ds.load().assign(taxel_current=ds.taxel_current * 1000), tmp_path / "mA.nc")
    run = tmp_path / "run"  # a finished fit: a refused --overwrite must not set it aside
    assert main(["fit", str(EGG), "--out", str(run), *FAST]) == 0
    before = _snapshot(run)
    capsys.readouterr()
    for argv in (
        ["fit", str(big), "--out", str(tmp_path / "o")],
        ["fit", str(big), "--out", str(run), "--overwrite"],
        ["calibrate", str(big), "--object", "sphere", "--out", str(tmp_path / "c.toml")],
    ):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "'taxel_current' reaches" in err[0] and "full scale" in err[0]
    assert not (tmp_path / "o").exists() and _snapshot(run) == before


def test_the_cache_keeps_each_cpu_and_jax_build_apart(tmp_path, monkeypatch):
    """JAX's cache keys do not hold the CPU's features: programs compiled on one host of a shared home folder must
    not reach a host of another CPU. The tag changes with the CPU's features and with the JAX build."""
    from bayestouch import backend

    def tag_with(flags):
        info = tmp_path / "cpuinfo"
        info.write_text(f"processor\t: 0\nflags\t\t: {flags}\n")
        return backend.build_tag(info)

    base = tag_with("fpu sse2 avx2")
    assert tag_with("avx2 sse2 fpu") == base  # the features, not their order
    assert tag_with("fpu sse2 avx2 avx512f") != base
    assert backend.jax.__version__ in base and "/" not in base
    assert backend.build_tag(tmp_path / "none")  # no cpuinfo: the processor's name stands in
    monkeypatch.setattr(backend.jax, "__version__", "0.0.1")
    assert tag_with("fpu sse2 avx2") != base


def test_the_cache_variable_means_what_a_user_writes(tmp_path, monkeypatch, capsys):
    """``~`` expands (it made a folder literally named ~), ``1``/``on`` keep the default place (``1`` made a folder
    named 1), ``off`` turns the cache off, and a file given as the folder is said on stderr."""
    from bayestouch import backend

    monkeypatch.setattr(backend.jax.config, "update", lambda *a: None)  # this process's JAX is left as it is
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("BAYESTOUCH_JAX_CACHE", "~/jaxcache")
    tag = backend.build_tag()
    assert backend.enable_compilation_cache() == str(tmp_path / "home" / "jaxcache" / tag)
    assert not (tmp_path / "~").exists()
    for on in ("1", "on", "True"):
        monkeypatch.setenv("BAYESTOUCH_JAX_CACHE", on)
        assert backend.enable_compilation_cache() == str(tmp_path / "xdg" / "bayestouch" / "jax" / tag)
    assert not (tmp_path / "1").exists()
    for off in ("0", "off", "no", ""):
        monkeypatch.setenv("BAYESTOUCH_JAX_CACHE", off)
        assert backend.enable_compilation_cache() is None
    (tmp_path / "afile").write_text("x")
    monkeypatch.setenv("BAYESTOUCH_JAX_CACHE", str(tmp_path / "afile"))
    capsys.readouterr()
    assert backend.enable_compilation_cache() is None
    assert "BAYESTOUCH_JAX_CACHE" in capsys.readouterr().err
