"""How casest's C exports build: every export (EKF, IEKF, UKF in double and single precision,
recursive least squares, recursive ML, the batch two-stage estimator) compiles without a warning
under gcc and clang with strict flags in C99 and C11; cppcheck's MISRA C:2012 addon finds no
mandatory or required violation in casest's wrapper or header, and in the generated kernels only
the deviations of the record; the single-precision filters, cross-compiled for 32-bit ARM with
hard float, hold no double-precision instruction and run under qemu to within a tolerance derived
from float's rounding and the record's conditioning; the header's memory figures are the target's
sizeof. Each part skips, saying which tool is missing, where the machine lacks it.

Truth: the short-period model file's record (models/short_period.py, seed 3) filtered by casest
in double precision; the struct sizes by the compilers' sizeof.
"""

import re
import shutil
import subprocess

import numpy as np
import pytest

import casest
from casest.export.batch_c import export_two_stage_c
from casest.export.filter_c import export_c
from casest.export.misra import KERNEL_DEVIATIONS, misra_findings
from casest.export.rls_c import export_rls_c
from casest.export.rml_c import export_rml_c
from casest.filters.compiled_passes import record_columns
from c_export_drivers import FLOAT_DRIVER

STRICT = ["-Wall", "-Wextra", "-Wpedantic", "-Wshadow", "-Wconversion", "-Wdouble-promotion", "-Werror"]
FILTERS = [f"{kind}-{precision}" for kind in ("ekf", "iekf", "ukf") for precision in ("double", "single")]
EXPORTS = FILTERS + ["rls", "rml", "batch"]
ARM = ("arm-linux-gnueabihf-gcc", "arm-linux-gnueabihf-objdump", "arm-linux-gnueabihf-nm", "qemu-arm")
ARM_FLAGS = ["-std=c99", "-O2", "-mfpu=vfpv4-d16", "-mfloat-abi=hard"]


def _short_period_filter(kind: str, alpha=None):
    m = casest.load_model_file("short_period")
    model = m.model()
    R = [m.NOISE_STD[n] ** 2 for n in model.output_names]
    arguments = (model, m.TRUTH, {"q": 1e-4}, R, np.eye(2) * 1e-4)
    if kind == "ukf":
        return casest.UnscentedKalmanFilter(*arguments, x0=np.zeros(2), **({"alpha": alpha} if alpha else {}))
    return casest.ExtendedKalmanFilter(*arguments, x0=np.zeros(2), iterated=kind == "iekf")


@pytest.fixture(scope="module")
def exports(tmp_path_factory):
    """Every export, written once: ``{key: (folder, name, paths)}``."""
    root = tmp_path_factory.mktemp("exports")
    written = {}
    for key in FILTERS:
        kind, precision = key.split("-")
        written[key] = (root / key, "fl", export_c(_short_period_filter(kind), root / key, name="fl",
                                                   precision=precision))
    scalar2 = casest.load_model_file("scalar2").model()
    written["rls"] = (root / "rls", "rls", export_rls_c(scalar2, root / "rls", name="rls"))
    written["rml"] = (root / "rml", "rml", export_rml_c(scalar2, root / "rml", name="rml"))
    written["batch"] = (root / "batch", "ts", export_two_stage_c(scalar2, 40, root / "batch", name="ts",
                                                                 sweep_settings=casest.SweepSettings(n_candidates=16)))
    return written


@pytest.mark.parametrize("compiler", ["gcc", "clang"])
@pytest.mark.parametrize("standard", ["c99", "c11"])
@pytest.mark.parametrize("key", EXPORTS)
def test_every_export_compiles_without_a_warning_under_strict_flags(tmp_path, exports, key, compiler, standard):
    """-std=c99 and -std=c11 with -Wall -Wextra -Wpedantic -Wshadow -Wconversion -Wdouble-promotion
    -Werror, gcc and clang (-O2; the batch estimator's large file at -O1, as its README says)."""
    if shutil.which(compiler) is None:
        pytest.skip(f"{compiler} is not installed")
    folder, name, paths = exports[key]
    level = "-O1" if key == "batch" else "-O2"
    run = subprocess.run([compiler, f"-std={standard}", level, *STRICT, f"-I{folder}", "-c", paths["source"], "-o",
                          str(tmp_path / "x.o")], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[:3000]


@pytest.mark.parametrize("key", ["ekf-double", "ukf-single", "rls", "rml"])
def test_misra_finds_no_required_violation_in_casests_code_and_only_recorded_deviations_in_the_kernel(exports, key):
    """cppcheck's MISRA C:2012 addon: no mandatory or required finding in the wrapper or the
    header; every mandatory or required finding in the generated kernel is a rule of the deviation
    record (casest.export.misra.KERNEL_DEVIATIONS), so that a new kind of violation fails here."""
    folder, name, _ = exports[key]
    findings = misra_findings(folder, name)
    if findings is None:
        pytest.skip("cppcheck is not installed (apt install cppcheck)")
    serious = [f for f in findings if f.category != "advisory"]
    ours = [f for f in serious if f.part != "kernel"]
    assert not ours, ours[:5]
    unrecorded = {f.rule for f in serious if f.part == "kernel"} - set(KERNEL_DEVIATIONS)
    assert not unrecorded, [f for f in serious if f.rule in unrecorded][:5]
    assert any(f.part == "kernel" for f in findings)  # the addon ran over the generated code


def _arm_tolerance(flt, data) -> float:
    """The single-precision filter's tolerance relative to each state's range: the unit roundoff of
    float, u = 2^-24, times the conditioning of the update's solve (the largest condition number
    of the innovation covariance scaled to unit diagonal), accumulated over the filter's memory
    1 / (1 - rho), rho the largest spectral radius of the error transition Phi P(k|k) P(k|k-1)^-1."""
    r = flt.filter(data, compiled=True)
    S = r.innovation_covariance
    d = 1.0 / np.sqrt(np.diagonal(S, axis1=1, axis2=2))
    kappa = np.linalg.cond(S * d[:, :, None] * d[:, None, :]).max()
    n = len(r.transition)  # between samples: one fewer than the samples
    transitions = r.transition @ r.P_filtered[:n] @ np.linalg.inv(r.P_predicted[:n])
    rho = np.abs(np.linalg.eigvals(transitions)).max()
    return 2.0 ** -24 * kappa / (1.0 - rho)


SIZE_DRIVER = r"""
#include <stdio.h>
#include "fl.h"
int main(void) { printf("%u %u\n", (unsigned)sizeof(fl_t), (unsigned)FL_STRUCT_BYTES); return 0; }
"""


@pytest.mark.parametrize("kind", ["ekf", "ukf"])
def test_single_precision_runs_on_32_bit_arm_without_double_arithmetic(tmp_path, kind):
    """Cross-compiled for ARMv7 hard float (vfpv4-d16) under the strict flags: no .f64 instruction
    and no double libm symbol in the object; run under qemu-arm over the short-period record (1001
    samples), every state within the derived tolerance (:func:`_arm_tolerance`: 3.1e-5 of the range
    here; measured 2.2e-7 for the EKF, 5.1e-7 for the UKF with alpha = 1) of casest's double filter,
    P positive definite; sizeof(fl_t) on the target is the header's FL_STRUCT_BYTES."""
    missing = [tool for tool in ARM if shutil.which(tool) is None]
    if missing:
        pytest.skip(f"{missing} not installed (apt install gcc-arm-linux-gnueabihf qemu-user)")
    flt = _short_period_filter(kind, alpha=1.0)
    model, data = flt.model, casest.load_model_file("short_period").simulate(seed=3)
    out = tmp_path / "out"
    paths = export_c(flt, out, name="fl", precision="single")
    obj, exe, sizes = tmp_path / "fl.o", tmp_path / "driver", tmp_path / "sizes"
    subprocess.run(["arm-linux-gnueabihf-gcc", *ARM_FLAGS, *STRICT, "-c", paths["source"], "-o", str(obj)], check=True)
    disassembly = subprocess.run(["arm-linux-gnueabihf-objdump", "-d", str(obj)], capture_output=True,
                                 text=True, check=True).stdout
    assert disassembly.count(".f64") == 0 and disassembly.count(".f32") > 0
    undefined = {u.split("@")[0] for u in subprocess.run(["arm-linux-gnueabihf-nm", "-u", str(obj)],
                                                         capture_output=True, text=True).stdout.split()}
    assert not undefined & {"sqrt", "log", "exp", "fabs", "pow", "__aeabi_dadd", "__aeabi_dmul"}, undefined
    (tmp_path / "driver.c").write_text(FLOAT_DRIVER)
    (tmp_path / "sizes.c").write_text(SIZE_DRIVER)
    for source, target in (("driver.c", exe), ("sizes.c", sizes)):
        extra = [paths["source"]] if source == "driver.c" else []
        subprocess.run(["arm-linux-gnueabihf-gcc", *ARM_FLAGS, f"-I{out}", str(tmp_path / source), *extra, "-lm",
                        "-o", str(target)], check=True)
    qemu = ["qemu-arm", "-L", "/usr/arm-linux-gnueabihf"]
    size, stated = subprocess.run([*qemu, str(sizes)], capture_output=True, text=True, check=True).stdout.split()
    assert size == stated
    D, _ = record_columns(model, data)
    numbers = [*flt.x0, *flt.P0.reshape(-1, order="F"), *flt.theta, *flt.Qc.reshape(-1, order="F"),
               *getattr(flt, "input_noise", np.zeros(len(model.inputs))), *flt.R.reshape(-1, order="F")]
    text = f"{data.n_samples} " + " ".join(repr(float(v)) for v in numbers) + "\n" + \
        "\n".join(" ".join(repr(float(v)) for v in row) for row in D)
    lines = subprocess.run([*qemu, str(exe)], input=text, capture_output=True, text=True, timeout=600,
                           check=True).stdout.splitlines()
    result = np.array([[float(v) for v in line.split()] for line in lines])
    assert result.shape == (data.n_samples, 6)
    reference = flt.filter(data, compiled=True).x_filtered
    deviation = np.abs(result[:, :2] - reference).max(axis=0) / np.abs(reference).max(axis=0)
    assert np.all(deviation <= _arm_tolerance(flt, data)), deviation
    P = result[:, 2:6].reshape(-1, 2, 2, order="F")
    assert np.all(np.linalg.eigvalsh(0.5 * (P + P.transpose(0, 2, 1))) > 0)


@pytest.mark.parametrize("key", EXPORTS)
def test_the_header_states_the_stack_a_call_uses_and_the_work_it_holds(exports, key):
    """The header defines NAME_STACK_BYTES (measured by gcc's call graph at export), below 16 KiB for
    every export here, and NAME_WORK_BYTES; the batch estimator's work is the caller's struct."""
    if shutil.which("gcc") is None:
        pytest.skip("gcc is not installed: the stack is not measured")
    folder, name, paths = exports[key]
    header = open(paths["header"]).read()
    if f"{name.upper()}_STACK_BYTES is not defined" in header:
        pytest.skip("this gcc cannot report its call graph (-fcallgraph-info, GCC 10 and later)")
    stack = int(re.search(rf"#define {name.upper()}_STACK_BYTES (\d+)U", header).group(1))
    assert 0 < stack < 16384
    assert f"#define {name.upper()}_WORK_BYTES" in header and f"#define {name.upper()}_STRUCT_BYTES" in header
