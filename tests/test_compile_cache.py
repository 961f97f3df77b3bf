"""The persistent cache of compiled functions (casest._casadi.numerics.compile_function, casest.ccache).

Each scenario runs in fresh processes (the in-process memo would hide the disk cache) with
a private cache folder; the compiler's outcomes are read from compile_stats().
"""

import glob
import json
import os
import subprocess
import sys

import pytest

from casest._casadi.numerics import compiler_available

pytestmark = pytest.mark.skipif(not compiler_available(), reason="no C compiler")

SCRIPT = """
import json, os, sys
import casadi as ca
from casest._casadi.numerics import compile_function, compile_stats
x = ca.SX.sym("x", 3)
f = ca.Function("cache_probe", [x], [ca.sin(x) * float(sys.argv[1]) + ca.sumsqr(x)])
cwd = os.getcwd(); before = sorted(os.listdir(cwd))
g = compile_function(f)
value = [float(v) for v in g([0.1, 0.2, 0.3]).full().ravel()]
assert os.getcwd() == cwd and sorted(os.listdir(cwd)) == before  # the working folder is left alone
print(json.dumps({"stats": compile_stats(), "value": value}))
"""


def run(cache, factor="2.0", cwd=None):
    env = {**os.environ, "CASEST_CACHE_DIR": str(cache)}
    if cwd is not None:
        cwd = os.path.join(cwd, "work")
        os.makedirs(cwd, exist_ok=True)
    out = subprocess.run([sys.executable, "-c", SCRIPT, factor], env=env, capture_output=True, text=True, cwd=cwd,
                         check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_hit_and_miss_after_a_change(tmp_path):
    first = run(tmp_path / "cache", cwd=tmp_path)
    assert first["stats"] == {"compiled": 1, "hit": 0, "rebuilt": 0}
    second = run(tmp_path / "cache", cwd=tmp_path)
    assert second["stats"] == {"compiled": 0, "hit": 1, "rebuilt": 0}
    assert second["value"] == first["value"]
    changed = run(tmp_path / "cache", factor="3.0", cwd=tmp_path)  # another model: another entry
    assert changed["stats"] == {"compiled": 1, "hit": 0, "rebuilt": 0}
    assert len(glob.glob(str(tmp_path / "cache" / "*.so"))) == 2


def test_concurrent_processes_build_one_entry(tmp_path):
    env = {**os.environ, "CASEST_CACHE_DIR": str(tmp_path / "cache")}
    (tmp_path / "work").mkdir()
    procs = [subprocess.Popen([sys.executable, "-c", SCRIPT, "5.0"], env=env, stdout=subprocess.PIPE, text=True,
                              cwd=tmp_path / "work") for _ in range(3)]
    results = [json.loads(p.communicate()[0].strip().splitlines()[-1]) for p in procs]
    assert all(p.returncode == 0 for p in procs)
    assert sum(r["stats"]["compiled"] for r in results) == 1  # the others waited on the lock and took it
    assert sum(r["stats"]["hit"] for r in results) == 2
    assert all(r["value"] == results[0]["value"] for r in results)
    assert len(glob.glob(str(tmp_path / "cache" / "*.so"))) == 1
    assert not glob.glob(str(tmp_path / "cache" / "*.tmp*"))


def test_corrupt_entry_is_rebuilt(tmp_path):
    first = run(tmp_path / "cache", cwd=tmp_path)
    (so,) = glob.glob(str(tmp_path / "cache" / "*.so"))
    with open(so, "r+b") as fh:  # damage the library
        fh.seek(100)
        fh.write(b"\0" * 64)
    again = run(tmp_path / "cache", cwd=tmp_path)
    assert again["stats"] == {"compiled": 0, "hit": 0, "rebuilt": 1}
    assert again["value"] == first["value"]
    assert run(tmp_path / "cache", cwd=tmp_path)["stats"]["hit"] == 1


def test_a_truncated_library_with_a_matching_digest_is_rebuilt_not_loaded(tmp_path):
    """Truth: a library cut short maps past its end (a bus error if loaded); its digest file
    written again to match must not make it loadable."""
    from casest._casadi.ccache import entry_digest

    first = run(tmp_path / "cache", cwd=tmp_path)
    (so,) = glob.glob(str(tmp_path / "cache" / "*.so"))
    data = open(so, "rb").read()[:-4096]
    with open(so, "wb") as fh:
        fh.write(data)
    with open(so[:-3] + ".sha256", "w") as fh:
        fh.write(entry_digest(so, data))
    again = run(tmp_path / "cache", cwd=tmp_path)
    assert again["stats"] == {"compiled": 0, "hit": 0, "rebuilt": 1} and again["value"] == first["value"]


def test_another_entrys_library_copied_over_is_rebuilt(tmp_path):
    """Truth: the function of factor 2 must give factor 2's values even when factor 3's library and
    its digest file are copied under its entry's names (the digest binds the entry's name)."""
    first = run(tmp_path / "cache", "2.0", cwd=tmp_path)
    (mine,) = glob.glob(str(tmp_path / "cache" / "*.so"))
    run(tmp_path / "cache", "3.0", cwd=tmp_path)
    (other,) = [p for p in glob.glob(str(tmp_path / "cache" / "*.so")) if p != mine]
    for suffix in (".so", ".sha256"):
        with open(other[:-3] + suffix, "rb") as src, open(mine[:-3] + suffix, "wb") as dst:
            dst.write(src.read())
    again = run(tmp_path / "cache", "2.0", cwd=tmp_path)
    assert again["stats"]["rebuilt"] == 1 and again["value"] == first["value"]


def test_cache_command_clears(tmp_path):
    run(tmp_path / "cache", cwd=tmp_path)
    env = {**os.environ, "CASEST_CACHE_DIR": str(tmp_path / "cache")}
    out = subprocess.run([sys.executable, "-m", "casest", "cache", "clear"], env=env, capture_output=True, text=True)
    assert out.returncode == 0 and "removed" in out.stdout
    assert not glob.glob(str(tmp_path / "cache" / "*.so"))


def test_clearing_the_cache_removes_the_markers_of_sums_compiled_ahead(tmp_path, monkeypatch):
    # a marker left behind would stop the next process from compiling the sums ahead again
    from casest._casadi.numerics import clear_cache

    monkeypatch.setenv("CASEST_CACHE_DIR", str(tmp_path / "cache"))
    (tmp_path / "cache").mkdir()
    (tmp_path / "cache" / "ahead_0123").touch()
    (tmp_path / "cache" / "keep.txt").touch()
    assert clear_cache() == 1
    assert [p.name for p in (tmp_path / "cache").iterdir()] == ["keep.txt"]


def test_fresh_model_object_reuses_the_built_functions():
    # same structure, new object: no new compiled function, the same NLP object
    import casest
    from casest._casadi.numerics import COMPILE_STATS
    from casest.two_stage.solve.nlps import full_nlp

    module = casest.load_model_file("scalar2")
    data = module.simulate(0)
    settings = casest.SolverSettings(jit=True)
    first = casest.estimate(module.model(), data, solver_settings=settings)
    built = COMPILE_STATS["jit_functions"]
    second = casest.estimate(module.model(), data, solver_settings=settings)
    assert COMPILE_STATS["jit_functions"] == built
    assert second.cost == first.cost
    a, b = module.model(), module.model()
    assert a.structure_key == b.structure_key
    problem_a, problem_b = casest.Problem(a, data), casest.Problem(b, data)
    part = casest.separate(a)
    assert full_nlp(problem_a, part, settings) is full_nlp(problem_b, part, settings)
    assert casest.load_model_file("scalar1").model().structure_key != a.structure_key


PREFETCH_SCRIPT = """
import json, sys
import casadi as ca
from casest._casadi.numerics import compile_function, compile_stats, prefetch_compile
x = ca.SX.sym("x", 3)
f = ca.Function("prefetch_probe", [x], [ca.cos(x) * float(sys.argv[1]) + ca.sumsqr(x)])
started = prefetch_compile(f, ("-O1",))
g = compile_function(f, ("-O1",))  # waits for the background process, then loads its library
value = [float(v) for v in g([0.1, 0.2, 0.3]).full().ravel()]
expected = [float(v) for v in f([0.1, 0.2, 0.3]).full().ravel()]
print(json.dumps({"started": started, "stats": compile_stats(), "value": value, "expected": expected}))
"""


def test_a_prefetched_compile_is_loaded_from_the_cache(tmp_path):
    """The background process compiles into the cache; the foreground compile then only loads it."""
    env = {**os.environ, "CASEST_CACHE_DIR": str(tmp_path / "cache")}
    out = subprocess.run([sys.executable, "-c", PREFETCH_SCRIPT, "3.5"], env=env, capture_output=True, text=True,
                         check=True)
    res = json.loads(out.stdout.strip().splitlines()[-1])
    assert res["started"] is True
    assert res["value"] == pytest.approx(res["expected"], rel=1e-14)
    assert res["stats"]["compiled"] == 0 and res["stats"]["hit"] == 1  # this process compiled nothing itself


AHEAD_SCRIPT = """
import json, sys
import numpy as np
import casest
from casest._casadi.numerics import compile_stats
from casest.two_stage.solve.nlps import compile_sums_ahead, sums_nlp
module = casest.load_model_file("scalar2")
model, data = module.model(), module.simulate(0, n=int(sys.argv[1]))
settings = casest.SolverSettings(jit=True, least_squares_solver="ipopt")
problem = casest.Problem(model, data)
partition = casest.separate(model)
started = compile_sums_ahead(problem, partition, settings)
before = compile_stats()
for mode in ("full", "reduced"):  # stage 2 builds the same sums: loaded from what ran ahead
    sums_nlp(model, partition, problem.n_samples, mode, settings)
after = compile_stats()
again = compile_sums_ahead(problem, partition, settings)
est = casest.estimate(model, data, solver_settings=settings)
print(json.dumps({"started": started, "again": again, "before": before, "after": after,
                  "theta": [float(v) for v in est.theta]}))
"""


@pytest.mark.parametrize("n_samples", [2500, 5000])
def test_stage_2_sums_compiled_ahead_are_loaded_from_the_cache(tmp_path, n_samples):
    """The sums stage 2 compiles (cost, gradient, Hessian, normal equations) start compiling in
    background processes before stage 1; stage 2 then compiles nothing itself, and a later
    process (the marker in the cache) does not build them ahead again. N = 2500: objects that
    CasADi's JIT links; N = 5000 (data outside the graph): libraries loaded without the JIT."""
    env = {**os.environ, "CASEST_CACHE_DIR": str(tmp_path / "cache")}
    runs = [json.loads(subprocess.run([sys.executable, "-c", AHEAD_SCRIPT, str(n_samples)], env=env, capture_output=True,
                                      text=True, check=True).stdout.strip().splitlines()[-1]) for _ in range(2)]
    first, second = runs
    assert first["started"] is True and first["again"] is False
    assert first["before"]["compiled"] == 0
    assert first["after"]["compiled"] == 0 and first["after"]["hit"] == 4  # cost, gradient, Hessian, normal eq.
    assert second["started"] is False  # the cache holds them: nothing built ahead
    assert second["after"]["hit"] == 4 and second["after"]["compiled"] == 0
    assert first["theta"] == second["theta"]


def test_the_source_written_ahead_always_has_a_name_casadi_accepts():
    # a temporary file's random suffix may hold "__", which CasADi's code generator refuses (it did
    # so 13 times in 300, and that function then compiled in the foreground)
    import casadi as ca

    from casest._casadi import numerics

    x = ca.SX.sym("x", 2)
    f = ca.Function("probe_sum_all", [x], [ca.sin(x[0]) * x[1]])
    paths = {numerics._jit_source(f) for _ in range(300)}
    assert len(paths) == 300 and all(os.path.exists(p) for p in paths)


def test_importing_casest_leaves_the_heavy_optional_modules_unloaded():
    """Cold start: ``import casest`` must not pull in scipy.signal (1.7 s of a 2.4 s import when it
    did), JAX, matplotlib or dask; the code that needs them imports them where it runs."""
    import subprocess
    import sys

    code = ("import sys, casest; print(sorted(m for m in ('scipy.signal', 'scipy.stats', 'jax', 'matplotlib', "
            "'distributed', 'dask') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout


def test_compiling_ahead_holds_in_its_own_thread_only():
    # another thread compiling meanwhile (a second estimate, say) must get compiled functions, not
    # the uncompiled ones the ahead block returns
    import threading

    from casest._casadi import numerics

    seen = {}
    with numerics.compiling_ahead():
        worker = threading.Thread(target=lambda: seen.update(other=numerics._ahead_depth()))
        worker.start()
        worker.join()
        seen["here"] = numerics._ahead_depth()
    assert seen == {"other": 0, "here": 1} and numerics._ahead_depth() == 0


LANES_SCRIPT = """
import json
import casest
from casest._casadi.numerics import compile_stats
scalar2 = casest.load_model_file("scalar2")
land = casest.sweep(scalar2.model(), scalar2.simulate(0), settings=casest.SweepSettings(n_candidates=20000))
print(json.dumps({"stats": compile_stats(), "best": [float(v) for v in land.best_xi2]}))
"""


def test_a_truncated_lane_library_is_rebuilt_not_loaded(tmp_path):
    """A damaged SIMD stage-1 library in the cache (truncated) crashed every later sweep with a bus
    error; its digest no longer matches, so it is compiled again."""
    env = {**os.environ, "CASEST_CACHE_DIR": str(tmp_path / "cache")}

    def sweep():
        out = subprocess.run([sys.executable, "-c", LANES_SCRIPT], env=env, capture_output=True, text=True,
                             cwd=tmp_path)
        assert out.returncode == 0, out.stderr[-2000:]
        return json.loads(out.stdout.strip().splitlines()[-1])

    first = sweep()
    libraries = glob.glob(str(tmp_path / "cache" / "lanes_*.so"))
    if not libraries:
        pytest.skip("the sweep did not use the SIMD lane library here")
    for path in libraries:
        assert os.path.exists(path[:-3] + ".sha256")
        with open(path, "r+b") as fh:
            fh.truncate(os.path.getsize(path) // 2)
    again = sweep()
    assert again["stats"]["rebuilt"] >= len(libraries)
    assert again["best"] == first["best"]


INDEX_SCRIPT = """
import json, sys
import casadi as ca
import numpy as np
from casest._casadi.numerics import compile_stats
from casest.backend.sums import Record, bound_sum
built = []
original_map = ca.Function.map
def counted_map(self, *args, **kwargs):
    built.append(self.name())
    return original_map(self, *args, **kwargs)
ca.Function.map = counted_map
x, z, p = ca.SX.sym("x", 2), ca.SX.sym("z"), ca.SX.sym("p", 2)
per_sample = ca.Function("index_probe", [x, z, p], [(z - p[0] * ca.sin(p[1] * x[0]) - x[1]) ** 2])
N = 5000
rng = np.random.default_rng(0)
X, Z = rng.standard_normal((N, 2)), rng.standard_normal((N, 1))
total = bound_sum(per_sample, N, threads=1, jit=True)
with Record(X, Z) as record:
    value = float(total(record.handle, [0.7, 1.3]))
print(json.dumps({"value": value, "built": built, "stats": compile_stats()}))
"""


def test_an_indexed_library_loads_without_building_its_block(tmp_path):
    # a sum whose data stay outside the graph finds its compiled block through the cache's index
    # in a later process: the block's map is not built again and the value is the same to the bit
    env = {**os.environ, "CASEST_CACHE_DIR": str(tmp_path / "cache")}

    def run_once():
        out = subprocess.run([sys.executable, "-c", INDEX_SCRIPT], env=env, capture_output=True, text=True, check=True)
        return json.loads(out.stdout.strip().splitlines()[-1])

    first = run_once()
    assert "index_probe" in first["built"] and first["stats"]["compiled"] == 1
    entries = glob.glob(str(tmp_path / "cache" / "*.index"))
    assert len(entries) == 1
    second = run_once()
    assert "index_probe" not in second["built"]  # loaded through the index
    assert second["stats"] == {"compiled": 0, "hit": 1, "rebuilt": 0}
    assert second["value"] == first["value"]
    with open(entries[0], "w") as fh:  # a damaged entry: the block is built again, from the cache
        fh.write("../elsewhere.so\nnothing\n")
    third = run_once()
    assert "index_probe" in third["built"] and third["stats"]["compiled"] == 0
    assert third["value"] == first["value"]


def test_a_full_cache_folder_falls_back_to_building_outside_it(tmp_path, monkeypatch):
    """A cache folder that cannot take the library (ENOSPC, simulated where the staged copy is
    written into it) costs the cache, not the computation: one warning, a working library."""
    import ctypes
    import errno
    import shutil

    from casest._casadi import c_library, cache_folder

    cache = tmp_path / "cache"
    monkeypatch.setenv("CASEST_CACHE_DIR", str(cache))
    cache_folder._CACHE_STATE.clear()
    real_copy = shutil.copyfile

    def full(src, dst, *args, **kwargs):
        if str(dst).startswith(str(cache)):
            raise OSError(errno.ENOSPC, "No space left on device", str(dst))
        return real_copy(src, dst, *args, **kwargs)

    monkeypatch.setattr(shutil, "copyfile", full)
    source = "double casest_probe_twice(double x) { return 2.0 * x + %r; }\n" % float(os.getpid() % 97)
    with pytest.warns(RuntimeWarning, match="cannot take a library"):
        library = c_library.load_library(source, ("-O2", "-shared", "-fPIC"))
    twice = library.casest_probe_twice
    twice.restype, twice.argtypes = ctypes.c_double, [ctypes.c_double]
    assert twice(1.5) == 3.0 + float(os.getpid() % 97)
    assert not glob.glob(str(cache / "*.so"))
