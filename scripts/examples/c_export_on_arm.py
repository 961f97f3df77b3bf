#!/usr/bin/env python3
"""The single-precision EKF and UKF exports of ``models/short_period.py`` compiled for ARMv7
hard-float (``arm-linux-gnueabihf-gcc -mfpu=vfpv4-d16 -mfloat-abi=hard``) and run under
``qemu-arm`` on the model file's record (seed 3): their states against casest's double filter
(largest deviation over the record, relative to each state's range), the libm symbols the
object needs, and the count of double-precision (``.f64``) instructions in it.

    python3 scripts/examples/c_export_on_arm.py [--out FOLDER]

Needs ``apt install gcc-arm-linux-gnueabihf qemu-user`` (Debian); says what is missing otherwise.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", ".."))
sys.path.insert(0, os.path.join(HERE, "..", "..", "tests"))

import casest  # noqa: E402
from casest.export.filter_c import export_c  # noqa: E402
from casest.filters.compiled_passes import record_columns  # noqa: E402
from c_export_drivers import FLOAT_DRIVER  # noqa: E402

TOOLS = ("arm-linux-gnueabihf-gcc", "arm-linux-gnueabihf-objdump", "arm-linux-gnueabihf-nm", "qemu-arm")
ARM = ["-std=c99", "-O2", "-mfpu=vfpv4-d16", "-mfloat-abi=hard"]


def run_one(kind: str, folder: str) -> str:
    """Export, cross-compile, run under qemu and compare one filter; its result line."""
    m = casest.load_model_file("short_period")
    model, data = m.model(), m.simulate(seed=3)
    R = [m.NOISE_STD[n] ** 2 for n in model.output_names]
    arguments = (model, m.TRUTH, {"q": 1e-4}, R, np.eye(2) * 1e-4)
    flt = casest.UnscentedKalmanFilter(*arguments, x0=np.zeros(2), alpha=1.0) if kind == "ukf" else \
        casest.ExtendedKalmanFilter(*arguments, x0=np.zeros(2))
    out = os.path.join(folder, kind)
    paths = export_c(flt, out, name="fl", precision="single")
    driver, exe, obj = (os.path.join(folder, f"{kind}_{p}") for p in ("driver.c", "driver", "fl.o"))
    with open(driver, "w") as fh:
        fh.write(FLOAT_DRIVER)
    subprocess.run(["arm-linux-gnueabihf-gcc", *ARM, "-Wall", "-Wextra", "-Wdouble-promotion", "-Werror", f"-I{out}",
                    "-c", paths["source"], "-o", obj], check=True)
    subprocess.run(["arm-linux-gnueabihf-gcc", *ARM, f"-I{out}", driver, paths["source"], "-lm", "-o", exe], check=True)
    D, _ = record_columns(model, data)
    noise = getattr(flt, "input_noise", np.zeros(len(model.inputs)))
    numbers = [*flt.x0, *flt.P0.reshape(-1, order="F"), *flt.theta, *flt.Qc.reshape(-1, order="F"), *noise,
               *flt.R.reshape(-1, order="F")]
    text = f"{data.n_samples} " + " ".join(repr(float(v)) for v in numbers) + "\n" + \
        "\n".join(" ".join(repr(float(v)) for v in row) for row in D)
    lines = subprocess.run(["qemu-arm", "-L", "/usr/arm-linux-gnueabihf", exe], input=text, capture_output=True,
                           text=True, check=True).stdout.splitlines()
    states = np.array([[float(v) for v in line.split()] for line in lines])[:, :2]
    reference = flt.filter(data, compiled=True).x_filtered
    deviation = float((np.abs(states - reference).max(axis=0) / np.abs(reference).max(axis=0)).max())
    undefined = [u for u in subprocess.run(["arm-linux-gnueabihf-nm", "-u", obj], capture_output=True,
                                           text=True).stdout.split() if u != "U"]
    disassembly = subprocess.run(["arm-linux-gnueabihf-objdump", "-d", obj], capture_output=True, text=True).stdout
    return (f"{kind}: {len(states)} samples, largest deviation {deviation:.3g} of the range; needs {undefined}; "
            f"{disassembly.count('.f64')} double and {disassembly.count('.f32')} single instructions")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", help="folder for the exports and binaries (default: a temporary one)")
    args = parser.parse_args(argv)
    missing = [t for t in TOOLS if shutil.which(t) is None]
    if missing:
        print(f"missing {missing}: apt install gcc-arm-linux-gnueabihf qemu-user", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="casest_arm_") as scratch:
        folder = args.out or scratch
        for kind in ("ekf", "ukf"):
            print(run_one(kind, folder), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
