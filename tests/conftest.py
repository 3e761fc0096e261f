import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from bayestouch.backend import jnp  # noqa: E402
from bayestouch.geometry import nellipsoid as ne  # noqa: E402


@pytest.fixture(scope="session", autouse=True)
def session_compilation_cache(tmp_path_factory):
    """Commands the tests run (in this process or as subprocesses) keep their compiled programs in this session's own
    folder, shared by the xdist workers, instead of the user's ``~/.cache/bayestouch/jax``: the suite neither reads
    programs a developer's earlier runs left there nor fills it (``BAYESTOUCH_JAX_CACHE`` set by hand is kept)."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # the workers' basetemps share their parent
    os.environ.setdefault("BAYESTOUCH_JAX_CACHE", str(root / "jax-cache"))
    return os.environ["BAYESTOUCH_JAX_CACHE"]


@pytest.fixture
def shape():
    """A tilted, off-centre n-ellipsoid with unequal axes (metres, radians)."""
    return ne.NEllipsoid(
        jnp.array([0.01, 0.02, -0.01]), jnp.array([0.03, 0.02, 0.015]), jnp.array([0.3, 0.7, -1.1]), jnp.array(3.0)
    )


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
