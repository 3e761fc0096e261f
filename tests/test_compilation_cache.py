"""The persistent compilation cache's folder stays under its bound: least recently used programs go first."""

import os

import pytest

from bayestouch import backend

BUILD = "jax0.10.2-jaxlib0.10.2-x86_64-6a93d771884c"  # a backend.build_tag() subfolder


def _entry(folder, name, size, used):
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    path.write_bytes(b"x" * size)
    os.utime(path, (used, used))
    return path


def test_prune_deletes_the_least_recently_used_until_the_share_kept(tmp_path):
    old_build, build = tmp_path / "jax0.9.0-jaxlib0.9.0-x86_64-aaaa", tmp_path / BUILD
    oldest = _entry(old_build, "a-cache", 400, 1_000)  # a JAX build long gone
    older = _entry(build, "b-cache", 300, 2_000)
    recent = _entry(build, "c-cache", 300, 3_000)
    newest = _entry(build, "d-cache", 200, 4_000)
    assert backend.prune_compilation_cache(tmp_path, max_bytes=1_200) == 0  # 1,200 bytes: at the bound, kept
    assert all(p.exists() for p in (oldest, older, recent, newest))
    # over a 1,000-byte bound: down to 750 bytes, oldest first (400 + 300 go, 500 left)
    assert backend.prune_compilation_cache(tmp_path, max_bytes=1_000, keep=0.75) == 700
    assert not oldest.exists() and not older.exists() and recent.exists() and newest.exists()


def test_prune_counts_a_read_as_a_use(tmp_path):
    read_lately = _entry(tmp_path / BUILD, "a-cache", 500, 1_000)
    os.utime(read_lately, (5_000, 1_000))  # accessed after the other was written
    written_later = _entry(tmp_path / BUILD, "b-cache", 500, 2_000)
    assert backend.prune_compilation_cache(tmp_path, max_bytes=800, keep=1.0) == 500
    assert read_lately.exists() and not written_later.exists()


def test_prune_leaves_everything_but_the_programs_alone(tmp_path):
    """A folder given as the cache (``BAYESTOUCH_JAX_CACHE=~/.cache``) may hold other things: only the build
    subfolders' ``*-cache`` files count and go."""
    mine = _entry(tmp_path / "pip", "wheel.whl", 5_000, 1_000)  # someone else's, old and large
    other = _entry(tmp_path / BUILD, "notes.txt", 5_000, 1_000)
    program = _entry(tmp_path / BUILD, "jit_f-0123-cache", 500, 2_000)
    assert backend.prune_compilation_cache(tmp_path, max_bytes=1_000) == 0
    assert backend.prune_compilation_cache(tmp_path, max_bytes=400) == 500
    assert mine.exists() and other.exists() and not program.exists()


def test_prune_refuses_a_share_outside_zero_to_one(tmp_path):
    with pytest.raises(ValueError, match="keep"):
        backend.prune_compilation_cache(tmp_path, max_bytes=10, keep=0.0)


def test_enabling_the_cache_prunes_its_folder(tmp_path, monkeypatch):
    monkeypatch.setattr(backend.jax.config, "update", lambda *a: None)  # this process's JAX is left as it is
    monkeypatch.setattr(backend, "CACHE_MAX_BYTES", 100)
    stale = _entry(tmp_path / "cache" / "jax0.1-jaxlib0.1-x86_64-0", "a-cache", 500, 1_000)
    monkeypatch.setenv("BAYESTOUCH_JAX_CACHE", str(tmp_path / "cache"))
    assert backend.enable_compilation_cache() == str(tmp_path / "cache" / backend.build_tag())
    assert not stale.exists()
