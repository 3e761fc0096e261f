"""The missed-mode audit of benchmarks/bench_sbc_missed.py picks the SBC sets it was written for: a truth beyond
every draw in a shape quantity, at a noise ratio where the likelihood holds."""

from __future__ import annotations

from benchmarks import bench_sbc_missed as bm
from benchmarks.bench_sbc_users import DRAWS, QUANTITIES


def _row(seed, ratio, **ranks):
    row = {"seed": str(seed), "noise_ratio": str(ratio)}
    row.update({f"rank_{q}": str(ranks.get(q, DRAWS // 2)) for q in QUANTITIES})
    return row


def test_audited_seeds_are_the_shape_misses_at_low_noise():
    rows = [
        _row(0, 1e-3, volume=DRAWS),  # volume above every draw: audited
        _row(1, 1e-3, a_2=0),  # a semi-axis below every draw: audited
        _row(2, 1e-3, x_G=0, n=DRAWS, sigma=0),  # beyond every draw, but not in a shape quantity
        _row(3, 0.05, a_1=0),  # a shape miss where the first-order likelihood does not hold
        _row(4, 1e-3, a_3=1, volume=DRAWS - 1),  # inside the draws' range, if only just
        _row(5, bm.NOISE_RATIO_MAX, a_3=0),  # the limit itself is excluded
    ]
    assert bm.audited_seeds(rows) == [0, 1]
