"""Write one result file of each kind casest can save, and its text report, with the casest found first on
sys.path: how the files under this folder were made, one folder per commit.

    git worktree add /tmp/at COMMIT
    PYTHONPATH=/tmp/at python3 tests/data/result_files/write_result_files.py OUT_FOLDER MODELS [FALLBACK_MODELS]

MODELS is that commit's ``models/`` folder; a model file it lacks is read from FALLBACK_MODELS
(8f8ea55 has no ``turbulent_longitudinal.py``: it was read from 1500515's). A kind the commit cannot
save (no ``to_json``) is reported and skipped. ``tests/test_result_files_of_earlier_versions.py``
loads the files with today's casest.
"""
import os
import sys

import casadi as ca
import numpy as np

import casest

def main(out: str, models: str, fallback: str) -> None:
    """Write each kind's file and report into ``out``, the models from ``models`` (else ``fallback``)."""
    os.makedirs(out, exist_ok=True)

    def load(name):
        path = os.path.join(models, name + ".py")
        return casest.load_model_file(path if os.path.exists(path) else os.path.join(fallback, name + ".py"))

    scalar1, sp, tl = load("scalar1"), load("short_period"), load("turbulent_longitudinal")
    rng = np.random.default_rng(4)
    x = rng.uniform(-1.0, 1.0, 200)
    v = rng.uniform(-1.0, 1.0, 200)
    z = 0.5 + 2.0 * x - 1.0 * v + 0.3 * x * v + 0.05 * rng.standard_normal(200)
    xs, vs = ca.SX.sym("x"), ca.SX.sym("v")
    columns, terms = {"x": x, "v": v, "z": z}, {"bias": 1, "x": xs, "v": vs, "xv": xs * vs}
    results = {
        "two_stage": lambda: casest.estimate(scalar1.model(), scalar1.simulate(seed=0)),
        "output_error": lambda: casest.estimate(sp.model(), sp.simulate(0), start=sp.TRUTH),
        "filter_error": lambda: casest.filter_error_estimate(tl.model(), tl.simulate(1, n_samples=300), tl.TURBULENCE_START,
                                                            start=tl.TRUTH, formulation="innovation"),
        "frequency": lambda: casest.frequency_domain_estimate(sp.model(), sp.simulate(0), 2 * np.pi * np.arange(1, 41) / sp.DURATION),
        "regression": lambda: casest.regress("z", terms, columns),
        "stepwise": lambda: casest.stepwise("z", terms, columns, always=["bias"]),
    }
    for kind, make in results.items():
        try:
            r = make()
            r.to_json(os.path.join(out, kind + ".json"))
            open(os.path.join(out, kind + ".report.txt"), "w").write(r.report() + "\n")
            print(kind, "written")
        except Exception as e:
            print(kind, "FAILED", type(e).__name__, e)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], sys.argv[3] if len(sys.argv) > 3 else sys.argv[2])
