"""pytest settings for the notebooks, which nbmake runs in a kernel of this interpreter (the project venv).

A kernel inherits the environment of the test that starts it, so while a notebook runs (and only then: the other
tests of the same worker must not see it) the environment gives it

* its small sizes (``BAYESTOUCH_NB_SMALL=1``: few strokes, steps and draws; set ``BAYESTOUCH_NB_SMALL=0`` to run
  the notebooks at their real sizes under pytest);
* a temporary folder for the session (``TMPDIR``, short, under /tmp): the notebooks write only into
  ``tempfile.mkdtemp()`` folders, which then lie in it, and it is removed at exit, so nothing is left in the
  repository or in /tmp;
* one JAX compilation cache in that folder: the notebooks compile the same forward model, and the second one
  to need it loads it from the cache.
"""

import atexit
import os
import shutil
import tempfile

import pytest

_HERE = os.path.dirname(os.path.abspath(__file__))
_session: list = []
_saved: dict = {}


def _is_notebook(item) -> bool:
    return str(item.path).endswith(".ipynb") and os.path.dirname(str(item.path)) == _HERE


def _notebook_env() -> dict:
    if not _session:
        base = "/tmp" if os.path.isdir("/tmp") else None
        _session.append(tempfile.mkdtemp(prefix="bt_nb_", dir=base))
        atexit.register(shutil.rmtree, _session[0], ignore_errors=True)
    env = {"BAYESTOUCH_NB_SMALL": os.environ.get("BAYESTOUCH_NB_SMALL", "1"), "OMP_NUM_THREADS": "1",
           "TMPDIR": _session[0]}
    if "JAX_COMPILATION_CACHE_DIR" not in os.environ:
        env["JAX_COMPILATION_CACHE_DIR"] = os.path.join(_session[0], "jax_cache")
        env["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0"
    return env


def pytest_collection_modifyitems(config, items):
    """Every notebook takes more than 10 s: mark it ``slow`` (``make test-fast`` leaves them out)."""
    for item in items:
        if _is_notebook(item):
            item.add_marker(pytest.mark.slow)


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    if _is_notebook(item):
        for key, value in _notebook_env().items():
            _saved[key] = os.environ.get(key)
            os.environ[key] = value


@pytest.hookimpl(trylast=True)
def pytest_runtest_teardown(item):
    if _is_notebook(item):
        for key, value in _saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
        _saved.clear()
