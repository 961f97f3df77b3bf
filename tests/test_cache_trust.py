"""The compile cache is used only where it is the user's alone (as ssh checks its keys).

Truths: the file modes set here (a group-writable cache folder; a cached library made
group-writable), and the caching compiler's own log of what it did (hit / compiled /
uncached) with the library it hands out still working.
"""

import os
import subprocess
import sys
import warnings

import pytest

from casest._casadi import ccache, numerics
from casest._casadi.numerics import compiler_available

SOURCE = "int answer(void) { return 42; }\n"


def _compile(folder, log, tmp_path, name):
    src = tmp_path / f"{name}.c"
    src.write_text(SOURCE)
    out = tmp_path / f"{name}.so"
    code = subprocess.run([sys.executable, "-S", "-E", ccache.__file__, str(folder), str(log), numerics.c_compiler(),
                           "-shared", "-fPIC", str(src), "-o", str(out)]).returncode
    return code, out


@pytest.fixture
def compiler():
    if not compiler_available():
        pytest.skip("no C compiler on this machine: the cache holds compiled libraries only")


def test_a_group_writable_cache_folder_is_skipped_with_a_warning(tmp_path, monkeypatch):
    folder = tmp_path / "shared_cache"
    folder.mkdir()
    os.chmod(folder, 0o775)
    monkeypatch.setenv("CASEST_CACHE_DIR", str(folder))
    from casest._casadi import cache_folder

    monkeypatch.setattr(cache_folder, "_CACHE_STATE", {})
    with pytest.warns(RuntimeWarning, match="others can write it"):
        assert not numerics.cache_usable()
    os.chmod(folder, 0o755)
    monkeypatch.setattr(cache_folder, "_CACHE_STATE", {})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert numerics.cache_usable()


def test_the_caching_compiler_does_not_take_a_library_others_can_write(tmp_path, compiler):
    folder, log = tmp_path / "cache", tmp_path / "log"
    code, out = _compile(folder, log, tmp_path, "first")
    assert code == 0 and out.exists() and log.read_text().split() == ["compiled"]
    assert _compile(folder, log, tmp_path, "second")[0] == 0 and log.read_text().split()[-1] == "hit"
    (library,) = [p for p in folder.iterdir() if p.suffix == ".so"]
    os.chmod(library, 0o777)  # anyone could have replaced it: it is rebuilt, not taken
    assert _compile(folder, log, tmp_path, "third")[0] == 0 and log.read_text().split()[-1] == "rebuilt"
    os.chmod(folder, 0o777)  # a folder others can write: no cache at all, the output still built
    code, out = _compile(folder, log, tmp_path, "fourth")
    assert code == 0 and out.exists() and log.read_text().split()[-1] == "rebuilt"
