"""XLA's compiled programs and the kernel's limit on memory maps: the counter and the release that keeps a long
process (a notebook, a benchmark, a test worker) under the limit."""

import sys

import numpy as np
import pytest

from bayestouch.backend import jax, jnp, memory_maps, release_compiled


def test_memory_maps_reads_the_count_and_the_limit(tmp_path):
    maps, limit = tmp_path / "maps", tmp_path / "max_map_count"
    maps.write_text("a\nb\nc\n")
    limit.write_text("65530\n")
    assert memory_maps(maps, limit) == (3, 65530)
    assert memory_maps(maps, tmp_path / "absent") is None
    limit.write_text("not a number\n")
    assert memory_maps(maps, limit) is None


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the map count is read from /proc")
def test_release_compiled_drops_the_programs_and_their_maps_only_past_the_threshold():
    @jax.jit
    def f(x):
        return jnp.sin(x) @ jnp.cos(x).T

    for n in range(1, 41):  # forty programs, one per shape: ~18 maps each
        f(jnp.ones((n, 2))).block_until_ready()
    used, allowed = memory_maps()
    assert f._cache_size() == 40 and used < allowed
    assert release_compiled(1.0) is False and f._cache_size() == 40  # under the limit: nothing dropped
    assert release_compiled(0.0) is True and f._cache_size() == 0
    assert memory_maps()[0] < used - 40 * 5  # the programs' maps went with them
    np.testing.assert_allclose(f(jnp.ones((3, 2))), np.full((3, 3), 2 * np.sin(1) * np.cos(1)))  # compiled again


def test_release_compiled_refuses_a_share_outside_zero_to_one():
    with pytest.raises(ValueError, match="fraction"):
        release_compiled(1.5)
