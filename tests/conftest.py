import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from bayestouch.backend import jnp, release_compiled  # noqa: E402
from bayestouch.geometry import nellipsoid as ne  # noqa: E402


@pytest.fixture
def shape():
    """A tilted, off-centre n-ellipsoid with unequal axes (metres, radians)."""
    return ne.NEllipsoid(
        jnp.array([0.01, 0.02, -0.01]), jnp.array([0.03, 0.02, 0.015]), jnp.array([0.3, 0.7, -1.1]), jnp.array(3.0)
    )


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture(scope="module", autouse=True)
def _release_compiled_programs():
    """A test worker runs about forty test files in one process and keeps every program each one compiled; past
    ~3,500 of them the kernel's limit on memory maps kills the worker inside XLA (see
    :func:`bayestouch.backend.release_compiled`). Drop them between files once half the limit is used, the fits' own
    threshold."""
    yield
    release_compiled()
