"""The fit says when its noise scale is comparable to the object (σ above NOISE_SIZE_LIMIT of the smallest
semi-axis), where the simulation-based calibration found its intervals too narrow (docs/sbc.md)."""

import json

import numpy as np

from bayestouch.cli import main
from bayestouch.inference.run import NOISE_SIZE_LIMIT, noise_to_size


def test_noise_to_size_is_the_median_ratio_to_the_smallest_axis():
    draws = np.zeros((2, 3, 11))
    draws[..., 3:6] = np.log([0.03, 0.01, 0.02])
    draws[..., 10] = np.log([[1e-4, 2e-4, 3e-4], [4e-4, 5e-4, 6e-4]])
    assert np.isclose(noise_to_size(draws), 0.035)  # median of 0.01–0.06 over a₃ = 1 cm


def test_a_fit_with_noise_a_tenth_of_the_object_says_so(tmp_path, capsys):
    """Contacts on a 2 cm sphere with 3 mm noise: NOISE on the command line, noise_large and a warning in
    summary.json; the same sphere at 0.1 mm noise (the control) raises nothing."""
    rng = np.random.default_rng(5)
    v = rng.normal(size=(80, 3))
    surface = 0.02 * v / np.linalg.norm(v, axis=1, keepdims=True)
    verdicts = {}
    for sd in (3e-3, 1e-4):
        path = tmp_path / f"pts{sd:g}.csv"
        np.savetxt(path, surface + sd * rng.normal(size=surface.shape), delimiter=",", header="x,y,z", comments="")
        out = tmp_path / f"fit{sd:g}"
        assert main(["fit", str(path), "--out", str(out), "--budget", "8", "--quiet"]) == 0
        d = json.loads((out / "summary.json").read_text())["diagnostics"]
        verdicts[sd] = (d["noise_large"], d["noise_to_smallest_axis"], capsys.readouterr())
    large, ratio, said = verdicts[3e-3]
    assert large and ratio > NOISE_SIZE_LIMIT and "NOISE: σ is" in said.out and "warning: noise:" in said.err
    large, ratio, said = verdicts[1e-4]
    assert not large and ratio < 0.01 and "NOISE" not in said.out
