"""pytest settings for the notebooks, which nbmake runs in a kernel of this interpreter (the project venv).

The kernels inherit this process's environment, so setting it here gives every notebook

* its small sizes (``BAYESTOUCH_NB_SMALL=1``: few strokes, steps and draws; set ``BAYESTOUCH_NB_SMALL=0`` to run
  the notebooks at their real sizes under pytest);
* a temporary folder for the session (``TMPDIR``): the notebooks write only into ``tempfile.mkdtemp()`` folders,
  which then lie in it, and it is removed at exit, so nothing is left in the repository or in /tmp;
* one JAX compilation cache in that folder: the notebooks compile the same forward model, and the second one
  to need it loads it from the cache.
"""

import atexit
import os
import shutil
import tempfile

os.environ.setdefault("BAYESTOUCH_NB_SMALL", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
_session = tempfile.mkdtemp(prefix="bayestouch_notebooks_")
atexit.register(shutil.rmtree, _session, ignore_errors=True)
os.environ["TMPDIR"] = _session  # for the kernels; this process's tempfile.gettempdir() is already fixed
if "JAX_COMPILATION_CACHE_DIR" not in os.environ:
    os.environ["JAX_COMPILATION_CACHE_DIR"] = os.path.join(_session, "jax_cache")
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")


def pytest_collection_modifyitems(config, items):
    """Every notebook takes more than 10 s: mark it ``slow`` (``make test-fast`` leaves them out)."""
    import pytest

    here = os.path.dirname(os.path.abspath(__file__))
    for item in items:
        if str(item.path).endswith(".ipynb") and os.path.dirname(str(item.path)) == here:
            item.add_marker(pytest.mark.slow)
