import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from bayestouch.backend import jnp  # noqa: E402
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
