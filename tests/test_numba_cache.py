"""With no writable place for numba's cache, hapticlab still imports and runs, and says where its kernels went."""

from __future__ import annotations

import os
import shutil
import sys
import textwrap

import pytest
from helpers import ROOT

from hapticlab import numba_cache

KERNEL = "import numpy as np; from hapticlab.core.aligner_kernel import _multiply; out = np.zeros(4); "
KERNEL += "_multiply(np.array([1.0, 0, 0, 0]), np.array([0, 1.0, 0, 0]), out); print('kernel', out.tolist())"


def test_writable_looks_at_the_nearest_folder_that_exists(tmp_path):
    assert numba_cache.writable(tmp_path / "not" / "yet")
    (tmp_path / "a_file").write_text("")
    assert not numba_cache.writable(tmp_path / "a_file" / "below")  # a file is no folder to make one in


@pytest.mark.skipif(
    os.geteuid() != 0 or shutil.which("unshare") is None, reason="a read-only bind mount needs root and unshare"
)
def test_a_read_only_install_and_home_cache_in_the_temporary_folder(tmp_path, run_command):
    """The checkout and the home folder mounted read-only (in a mount namespace of the command's own): the
    decorators would raise 'no locator available'; the kernels go to a folder of the temporary directory."""
    home, tmp = tmp_path / "home", tmp_path / "tmp"
    home.mkdir()
    tmp.mkdir()
    read_only = " && ".join(f"mount --bind {p} {p} && mount -o remount,bind,ro {p}" for p in (ROOT, home))
    script = f'{read_only} && exec {sys.executable} -c "{KERNEL}"'
    env = {**os.environ, "HOME": str(home), "XDG_CACHE_HOME": str(home / ".cache"), "TMPDIR": str(tmp)}
    env.pop("NUMBA_CACHE_DIR", None)
    result = run_command(["unshare", "-m", "sh", "-c", script], "a read-only install", env=env)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.strip() == "kernel [0.0, 1.0, 0.0, 0.0]"
    fallback = tmp / f"hapticlab-numba-{os.getuid()}"
    assert result.stderr.splitlines()[0] == (
        f"hapticlab: neither {ROOT} nor {home / '.cache' / 'numba'} can be written: the compiled kernels are "
        f"cached in {fallback} (set NUMBA_CACHE_DIR to choose)"
    )
    assert any(fallback.rglob("*.nbi")), "nothing cached in the fallback folder"


def test_with_no_writable_folder_at_all_the_kernels_compile_uncached(tmp_path, run_command):
    """Every folder refused (``os.access`` says no, as for a user with no write permission anywhere)."""
    script = textwrap.dedent(f"""
        import os
        os.access = lambda *args, **kwargs: False
        {KERNEL}
        print("caching", _multiply._cache.__class__.__name__)
    """)
    env = {**os.environ, "HOME": str(tmp_path), "TMPDIR": str(tmp_path)}
    env.pop("NUMBA_CACHE_DIR", None)
    result = run_command([sys.executable, "-c", script], "an install with no writable folder", env=env)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.splitlines() == ["kernel [0.0, 1.0, 0.0, 0.0]", "caching NullCache"]
    assert result.stderr.startswith("hapticlab: no folder to cache the compiled kernels in"), result.stderr
    assert not list(tmp_path.rglob("*.nbi"))
