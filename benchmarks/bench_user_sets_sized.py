"""The users'-like sets of :mod:`benchmarks.bench_user_sets` fitted by bayestouch with a size prior stated as a
user who knows the kind of object would state it (issue "Shape posteriors that hold up on real touch data":
``--size-prior``, "objects of 1–10 cm"), everything else the default fit.

The same 50 sets (seed 0) as ``user_sets.*``; only bayestouch is fitted (sage and the GPIS take no prior: their
figures are those of ``user_sets.md``). The generator's objects are 2.4–8 cm across along each axis (semi-axes
12–40 mm); the stated prior :data:`SIZE_PRIOR_M` is the issue's own example, wider than that on both sides, and
narrower than the default 1–30 cm (``models/priors.toml`` size_min, size_max). On one-sided sets only the size
prior bounds an axis no stroke reached, so this measures how much of the default fit's miscoverage
(``docs/contact_model.md``: eight of nine misses with the truth just below q05, on right-skewed volume posteriors)
is the default prior's upper tail.

Outputs: ``benchmarks/results/user_sets_sized.csv``, ``.json``, ``.md``. Run:
``OMP_NUM_THREADS=1 python -m benchmarks bench_user_sets_sized`` (``BAYESTOUCH_USER_SETS`` sets the count).
"""

from __future__ import annotations

from benchmarks import bench_user_sets as us

#: the stated size prior (m): the full length of each principal axis within 1–10 cm (central 95 %)
SIZE_PRIOR_M = (0.01, 0.10)


def bench_user_sets_sized() -> list[dict]:
    """bayestouch on the users'-like sets with :data:`SIZE_PRIOR_M` stated (module docstring): harness rows."""
    rows = us.bench_user_sets(methods=("bayestouch",), size_prior=SIZE_PRIOR_M, stem="user_sets_sized")
    return [r | {"size_prior_m": list(SIZE_PRIOR_M)} for r in rows]
