"""Regenerate the simulated data sets shipped in ``data/`` (see ``data/README.md``).

Run from the repository root::

    OMP_NUM_THREADS=1 .venv/bin/python data/regenerate.py            # everything (about a minute)
    OMP_NUM_THREADS=1 .venv/bin/python data/regenerate.py contacts   # only the files whose name has 'contacts'

Every file is made with a fixed seed, so a rerun reproduces it (the CSV files bit for bit on the same
platform; the recordings to floating-point round-off, see ``tests/test_data.py``). The paper's tables
(``table1_paper.csv``, ``table2_paper.csv``) are transcriptions, not generated.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

DATA = Path(__file__).resolve().parent
ROOT = DATA.parent
OBJECTS = ("egg", "sphere", "box", "cylinder")

#: ``bayestouch simulate`` settings of the shipped recordings: 3 strokes of 1 s at 25 frames/s, seed 0.
RECORDING_ARGS = ("--strokes", "3", "--seed", "0", "--duration", "1", "--rate", "25", "--quiet")
#: Contact sets: 12 random section paths at 1 cm/s sampled at 2 per second, plus isotropic Gaussian noise.
CONTACT_PATHS, CONTACT_RATE, CONTACT_NOISE_M, CONTACT_SEED = 12, 2.0, 1e-4, 7
#: The graphite plate's paths as ``bayestouch reproduce-paper`` walks them (``bayestouch.paper.plate_data``).
PLATE_PATHS, PLATE_RATE, PLATE_SEED = 25, 20.0, 0


def recording(name: str, out: Path) -> Path:
    """Simulated strokes of the virtual finger over ``models/objects/<name>.toml`` (``bayestouch simulate``)."""
    from bayestouch.cli import main

    rel = Path("models") / "objects" / f"{name}.toml"  # relative, so the file's attributes do not name this machine
    code = main(["simulate", "--object", str(rel), "--out", str(out), "--overwrite", *RECORDING_ARGS])
    if code:
        raise SystemExit(f"bayestouch simulate failed for {name} (exit {code})")
    return out


def contact_set(name: str, out: Path) -> Path:
    """Noisy contact points with the true outward normals, for ``bayestouch fit`` (x,y,z,nx,ny,nz)."""
    from bayestouch.io.contacts import save_contact_points
    from bayestouch.scene.objects import load_object
    from bayestouch.scene.paths import random_paths

    obj = load_object(ROOT / "models" / "objects" / f"{name}.toml")
    rng = np.random.default_rng(CONTACT_SEED)
    paths = random_paths(obj, CONTACT_PATHS, seed=rng, rate=CONTACT_RATE)
    pts = np.concatenate([p.points for p in paths])
    nrm = np.concatenate([p.normals for p in paths])
    pts = pts + rng.normal(0.0, CONTACT_NOISE_M, size=pts.shape)
    return save_contact_points(out, pts, normals=nrm)


def plate_paths(out: Path) -> Path:
    """The damaged graphite plate's 25 finger paths (half-sections, 1 cm/s, 20 samples/s), numbered from 1."""
    from bayestouch.io.files import write_csv_rows
    from bayestouch.scene.objects import load_object
    from bayestouch.scene.paths import random_paths

    obj = load_object(ROOT / "models" / "objects" / "graphite_plate.toml")
    paths = random_paths(obj, PLATE_PATHS, seed=PLATE_SEED, rate=PLATE_RATE, arc=np.pi)
    cols = ("path", "time", "x", "y", "z", "nx", "ny", "nz")
    rows = []
    for k, p in enumerate(paths, start=1):
        for t, x, n in zip(p.time.tolist(), p.points.tolist(), p.normals.tolist(), strict=True):
            rows.append(dict(zip(cols, (k, t, *x, *n), strict=True)))
    return write_csv_rows(out, rows, cols)


def targets() -> dict:
    """File name (relative to ``data/``) → function writing it to a given path."""
    out = {f"recordings/{o}.nc": (lambda p, o=o: recording(o, p)) for o in OBJECTS}
    out |= {f"contacts/{o}.csv": (lambda p, o=o: contact_set(o, p)) for o in OBJECTS}
    out["graphite_plate_paths.csv"] = plate_paths
    return out


def main(argv: list[str]) -> int:
    import os

    os.chdir(ROOT)
    for name, make in targets().items():
        if argv and not any(a in name for a in argv):
            continue
        path = make(DATA / name)
        print(f"wrote data/{name} ({path.stat().st_size / 1e3:.0f} kB)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
