"""The wheel: built from the repository, installed into a fresh virtual environment and run from an empty folder
elsewhere, it carries its parameter files and works (``bayestouch fit``, objects by name, ``bt.fit(array)`` taking up
the command line's run, with InferenceData). The new environment finds the dependencies in this one's site-packages
(a ``.pth`` line, which does not run this environment's editable-install hook), so no network is needed."""

import json
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import numpy as np
import pytest

from bayestouch.io.contacts import save_contact_points

ROOT = Path(__file__).resolve().parent.parent


def _run(cmd, cwd, timeout=600):
    r = subprocess.run([str(c) for c in cmd], cwd=cwd, capture_output=True, text=True, timeout=timeout)
    assert r.returncode == 0, f"{cmd[0]} {cmd[1:3]}: exit {r.returncode}\n{r.stderr[-2000:]}"
    return r


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy(ROOT / name, src / name)
    for name in ("bayestouch", "models"):  # a copy: the build writes build/ and egg-info beside its sources
        shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    pip = [sys.executable, "-m", "pip"]
    _run([*pip, "wheel", "-q", "--no-deps", "--no-build-isolation", "-w", tmp / "dist", src], tmp)
    (wheel,) = (tmp / "dist").glob("bayestouch-*.whl")
    venv = tmp / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", venv], tmp)
    py = venv / "bin" / "python"
    _run([*pip, "--python", py, "install", "-q", "--no-deps", "--no-index", wheel], tmp)
    site = Path(_run([py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], tmp).stdout.strip())
    (site / "deps_from_test.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    work = tmp / "elsewhere"
    work.mkdir()
    return wheel, venv, work


@pytest.mark.slow
def test_the_wheel_carries_the_parameter_files(installed):
    wheel, _, _ = installed
    names = set(zipfile.ZipFile(wheel).namelist())
    shipped = {f"bayestouch/models/{p.relative_to(ROOT / 'models')}" for p in (ROOT / "models").rglob("*.toml")}
    assert shipped and shipped <= names
    assert {"bayestouch/py.typed", "bayestouch/hardware/PROTOCOL.md", "bayestouch/api.py"} <= names
    # every package of the source tree is in the wheel (the explicit package list of pyproject.toml)
    for init in (ROOT / "bayestouch").rglob("__init__.py"):
        assert f"{init.relative_to(ROOT)}" in names, init


@pytest.mark.slow
def test_installed_package_runs_from_an_empty_folder(installed):
    _, venv, work = installed
    py, cli = venv / "bin" / "python", venv / "bin" / "bayestouch"
    where = _run([py, "-c", "import bayestouch.params as p; print(p.MODELS)"], work).stdout.strip()
    assert Path(where).is_relative_to(venv) and (Path(where) / "finger.toml").is_file()  # not the checkout's

    # objects by name resolve into the installed models (simulate, explore and device simulate take them so); running
    # `simulate` itself here cost half a minute of compilation and checked nothing the fit below does not
    egg = _run([py, "-c", "from bayestouch.scene.objects import resolve_object as r; print(r('egg'))"], work).stdout
    assert Path(egg.strip()).is_relative_to(venv) and Path(egg.strip()).is_file()

    rng = np.random.default_rng(0)
    d = rng.normal(size=(150, 3))
    pts = 0.02 * d / np.linalg.norm(d, axis=1, keepdims=True) + rng.normal(0, 3e-4, (150, 3))
    save_contact_points(work / "pts.csv", pts)
    # no wall-clock budget and a fixed length: a run the budget cut short (a loaded machine) is one the resume below
    # would rightly continue, and its volume would then differ
    _run(
        [cli, "fit", "pts.csv", "--out", "run", "--quiet", "--budget", "0", "--steps", "6000", "--no-early-stop"], work
    )
    v = json.loads((work / "run" / "summary.json").read_text())["derived"]["volume_m3"]["mean"]
    assert v == pytest.approx(4 / 3 * np.pi * 0.02**3, rel=0.05)

    # the notebook API on the same points takes up the command line's run (resume: the same data and options, its
    # finished chain and tempering stage read back, not sampled again) and gives its posterior; a fresh API fit of the
    # same points cost another cold compilation and half a minute of sampling
    script = (
        "import numpy as np, arviz as az, bayestouch as bt\n"
        "x = np.loadtxt('pts.csv', delimiter=',', skiprows=1)[:, :3]\n"
        "f = bt.fit(x, seed=0, progress=False, out='run', resume=True, budget_s=None, steps=6000,\n"
        "           stop_when_converged=False)\n"
        "assert isinstance(f.idata, az.InferenceData) and 'volume' in f.idata.posterior\n"
        "print(bt.__file__, float(f.idata.posterior['volume'].mean()))\n"
    )
    out = _run([py, "-c", script], work).stdout.split()
    assert Path(out[0]).is_relative_to(venv)
    assert float(out[1]) == pytest.approx(v, rel=1e-9)
