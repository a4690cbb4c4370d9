"""Compiled code is never loaded from a place others can write, nor when it differs from what was built."""
from __future__ import annotations

import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from udrobot_ctrl.dynamics import fastsim
from udrobot_files import caches

needs_gcc = pytest.mark.skipif(shutil.which("gcc") is None, reason="gcc not installed")

PLANT_C = """
#include <stdio.h>
__attribute__((constructor)) static void planted(void) {
    FILE *f = fopen("%s", "w");
    if (f) { fputs("planted code ran", f); fclose(f); }
}
"""


def _planted_library(tmp_path, marker):
    """A shared library whose loading (dlopen) writes ``marker``: any load of it is visible."""
    src = tmp_path / "planted.c"
    src.write_text(PLANT_C % marker)
    lib = tmp_path / "planted.so"
    subprocess.run(["gcc", "-shared", "-fPIC", str(src), "-o", str(lib)], check=True, capture_output=True)
    return lib


def _double():
    x = ca.SX.sym("x")
    return ca.Function("double_it", [x], [2 * x])


@pytest.fixture
def cache(tmp_path, monkeypatch):
    folder = tmp_path / "cache" / "fastsim"
    monkeypatch.setenv("UDROBOT_CACHE", str(folder))
    monkeypatch.setattr(caches, "_FALLBACKS", {})
    return folder


@needs_gcc
def test_cache_folder_is_private_and_library_hash_recorded(cache):
    fun = fastsim.compile_function(_double(), "k1")
    assert fun is not None and float(fun(3.0)) == 6.0
    assert stat.S_IMODE(os.stat(cache).st_mode) == 0o700
    lib = cache / "double_it_k1.so"
    assert (cache / "double_it_k1.so.sha256").read_text().strip() == fastsim._sha256(lib)
    assert stat.S_IMODE(os.stat(lib).st_mode) == 0o600


@needs_gcc
def test_planted_library_with_wrong_hash_is_not_loaded(cache, tmp_path):
    assert fastsim.compile_function(_double(), "k2") is not None
    marker = tmp_path / "ran.txt"
    lib = cache / "double_it_k2.so"
    shutil.copyfile(_planted_library(tmp_path, marker), lib)  # same owner and mode, different bytes
    with pytest.warns(RuntimeWarning, match="sha256"):
        fun = fastsim.compile_function(_double(), "k2")
    assert not marker.exists()
    assert float(fun(4.0)) == 8.0  # rebuilt from the casadi function
    assert (cache / "double_it_k2.so.sha256").read_text().strip() == fastsim._sha256(lib)


@needs_gcc
@pytest.mark.parametrize("attack", ["group_writable_dir", "symlinked_dir", "no_hash", "world_writable_lib"])
def test_planted_library_in_unsafe_place_is_not_loaded(cache, tmp_path, attack):
    marker = tmp_path / "ran.txt"
    planted = _planted_library(tmp_path, marker)
    name = "double_it_k3.so"
    if attack == "symlinked_dir":
        other = tmp_path / "elsewhere"
        other.mkdir(mode=0o700)
        cache.parent.mkdir(parents=True)
        cache.symlink_to(other)
        target = other
    else:
        cache.mkdir(parents=True, mode=0o700)
        target = cache
    shutil.copyfile(planted, target / name)
    if attack != "no_hash":
        (target / (name + ".sha256")).write_text(fastsim._sha256(target / name) + "\n")
    if attack == "group_writable_dir":
        os.chmod(cache, 0o770)
    if attack == "world_writable_lib":
        os.chmod(target / name, 0o666)
    with pytest.warns(RuntimeWarning):
        fun = fastsim.compile_function(_double(), "k3")
    assert not marker.exists()
    assert fun is None or float(fun(1.5)) == 3.0


def test_numba_cache_goes_to_a_private_user_folder(tmp_path, monkeypatch):
    from numba.core import config

    monkeypatch.setattr(config, "CACHE_DIR", config.CACHE_DIR)
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setattr(caches, "_FALLBACKS", {})
    folder = caches.configure_numba_cache()
    assert folder == str(tmp_path / "udrobot_ctrl" / "numba") == os.environ["NUMBA_CACHE_DIR"] == config.CACHE_DIR
    assert stat.S_IMODE(os.stat(folder).st_mode) == 0o700
    # a folder others can write is not used
    monkeypatch.delenv("NUMBA_CACHE_DIR")
    os.chmod(folder, 0o777)
    with pytest.warns(RuntimeWarning, match="writable by group or others"):
        other = caches.configure_numba_cache()
    assert other != folder and caches.unsafe_reason(other, want_dir=True) is None


def test_user_numba_cache_choice_is_kept(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "mine"))
    assert caches.configure_numba_cache() == str(tmp_path / "mine")


def test_rollout_compiled_still_matches_interpreted(cache):
    x0 = np.zeros(12)
    u = np.full((20, 4), 5.0)
    a = fastsim.Rollout("cfd:chin", 0.01, 20)(x0, u)
    b = fastsim.Rollout("cfd:chin", 0.01, 20, compile=shutil.which("gcc") is not None)(x0, u)
    np.testing.assert_allclose(a, b, atol=1e-12)


def test_unsafe_numba_cache_dir_chosen_by_the_user_is_not_used(tmp_path, monkeypatch):
    from numba.core import config

    monkeypatch.setattr(config, "CACHE_DIR", config.CACHE_DIR)
    monkeypatch.setattr(caches, "_FALLBACKS", {})
    shared = tmp_path / "shared"
    shared.mkdir()
    os.chmod(shared, 0o777)
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(shared))
    with pytest.warns(RuntimeWarning, match="writable by group or others"):
        folder = caches.configure_numba_cache()
    assert folder != str(shared) and os.environ["NUMBA_CACHE_DIR"] == folder == config.CACHE_DIR
    assert caches.unsafe_reason(folder, want_dir=True) is None
    monkeypatch.setattr(caches, "_FALLBACKS", {})
    link = tmp_path / "link"
    link.symlink_to(tmp_path / "mine_target", target_is_directory=True)
    (tmp_path / "mine_target").mkdir(mode=0o700)
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(link))
    with pytest.warns(RuntimeWarning, match="symbolic link"):
        assert caches.configure_numba_cache() != str(link)


NUMBA_SCRIPT = """
from udrobot_files.caches import configure_numba_cache
print(configure_numba_cache())
import numba

@numba.njit(cache=True)
def plus_one(x):
    return x + 1

print(plus_one(1))
"""


def _plant_index(folder, marker):
    """Replace every numba index (.nbi) under ``folder`` with a pickle whose loading writes ``marker``."""
    payload = (b"cbuiltins\nexec\n(V" + f"open({str(marker)!r}, 'w').write('planted code ran')".encode()
               + b"\ntR.")
    planted = 0
    for nbi in folder.rglob("*.nbi"):
        nbi.write_bytes(payload)
        planted += 1
    return planted


@pytest.mark.slow
def test_planted_pickle_in_a_world_writable_numba_cache_does_not_run(tmp_path):
    script = tmp_path / "kernel.py"
    script.write_text(NUMBA_SCRIPT)
    cache = tmp_path / "numba_cache"
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))

    def run():
        return subprocess.run([sys.executable, str(script)], env=env, capture_output=True, text=True, timeout=300)

    first = run()
    assert first.returncode == 0 and first.stdout.split()[-1] == "2", first.stderr
    marker = tmp_path / "ran.txt"
    assert _plant_index(cache, marker) >= 1
    os.chmod(cache, 0o777)  # anyone may now write the cache: nothing is loaded from it
    second = run()
    assert second.returncode == 0 and second.stdout.split()[-1] == "2", second.stderr
    assert "writable by group or others" in second.stderr and second.stdout.split()[0] != str(cache)
    assert not marker.exists()
    os.chmod(cache, 0o700)  # the control: the same planted index in a private folder is what numba loads
    third = run()
    assert marker.exists(), third.stderr


@pytest.mark.slow
def test_planted_pickle_behind_a_link_inside_a_private_numba_cache_does_not_run(tmp_path):
    """Issue 62: a private NUMBA_CACHE_DIR whose subfolders link to a world-writable folder: nothing loaded."""
    script = tmp_path / "kernel.py"
    script.write_text(NUMBA_SCRIPT)
    cache = tmp_path / "numba_cache"
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))

    def run():
        return subprocess.run([sys.executable, str(script)], env=env, capture_output=True, text=True, timeout=300)

    assert run().returncode == 0
    shared = tmp_path / "shared"
    shared.mkdir()
    os.chmod(shared, 0o777)
    for sub in [p for p in cache.iterdir() if p.is_dir()]:  # numba's per-source subfolders -> links out
        sub.rename(shared / sub.name)
        sub.symlink_to(shared / sub.name, target_is_directory=True)
    os.chmod(cache, 0o700)
    marker = tmp_path / "ran.txt"
    assert _plant_index(shared, marker) >= 1
    second = run()
    assert second.returncode == 0 and second.stdout.split()[-1] == "2", second.stderr
    assert "holds a symbolic link" in second.stderr and second.stdout.split()[0] != str(cache)
    assert not marker.exists()


@pytest.mark.parametrize("attack", ["open_parent", "link_inside", "writable_file_inside", "foreign_parent_link"])
def test_a_cache_folder_is_checked_along_its_whole_path_and_inside(tmp_path, monkeypatch, attack):
    monkeypatch.setattr(caches, "_FALLBACKS", {})
    parent = tmp_path / "p"
    parent.mkdir()
    folder = parent / "cache"
    folder.mkdir(mode=0o755)
    os.chmod(folder, 0o755)  # open to read: what is inside must then be closed to writes
    if attack == "open_parent":
        os.chmod(parent, 0o777)  # anyone may replace 'cache' (no sticky bit)
        expected = "writable by group or others without the sticky bit"
    elif attack == "link_inside":
        (folder / "sub").symlink_to(tmp_path, target_is_directory=True)
        expected = "holds a symbolic link"
    elif attack == "writable_file_inside":
        (folder / "index.nbi").write_bytes(b"x")
        os.chmod(folder / "index.nbi", 0o666)
        expected = "writable by group or others"
    else:
        if os.getuid() == 0:
            link = tmp_path / "owned_by_nobody"
            link.symlink_to(parent, target_is_directory=True)
            os.lchown(link, 65534, 65534)
            folder = link / "cache"
            expected = "owned by uid 65534"
        else:
            pytest.skip("needs root to give a link to another user")
    assert expected in (caches.path_unsafe_reason(folder) or "")
    with pytest.warns(RuntimeWarning, match="using a private temporary folder"):
        used = caches.private_dir(folder, "test")
    assert used != folder and caches.path_unsafe_reason(used) is None


def test_a_private_folder_with_the_users_umask_inside_and_a_sticky_parent_is_used(tmp_path, monkeypatch):
    monkeypatch.setattr(caches, "_FALLBACKS", {})
    sticky = tmp_path / "tmp"
    sticky.mkdir()
    os.chmod(sticky, 0o1777)  # like /tmp
    folder = sticky / "cache"
    folder.mkdir(mode=0o700)
    (folder / "sub").mkdir()
    os.chmod(folder / "sub", 0o775)  # numba's subfolder under umask 002: nobody else can reach it through 0700
    assert caches.path_unsafe_reason(folder) is None
    assert caches.private_dir(folder, "test") == folder


def test_the_cache_location_honours_xdg_cache_home(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    monkeypatch.delenv("UDROBOT_CACHE", raising=False)
    assert caches.user_cache_root() == tmp_path / "xdg" / "udrobot_ctrl"
    assert fastsim.cache_dir() == tmp_path / "xdg" / "udrobot_ctrl" / "fastsim"
    monkeypatch.setenv("XDG_CACHE_HOME", "relative/cache")  # the XDG spec: relative paths are ignored
    assert caches.user_cache_root() == Path.home() / ".cache" / "udrobot_ctrl"
