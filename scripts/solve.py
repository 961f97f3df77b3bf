#!/usr/bin/env python3
"""Estimate a model's parameters and print the report.

    python3 scripts/solve.py MODEL [--data CSV] [--stage1-data CSV] [--seed N]
                                   [--mode auto|reduced|full|alternating]
                                   [--covariance hessian|hessian-dof|gauss-newton|gauss-newton-dof]
                                   [--json OUT] [--save-data CSV]

MODEL is a file path or the name of a bundled model in models/ (scalar1, scalar2, ...).
Without --data the model file's simulate(seed) makes a data set with known truth, and
the truth is printed beside the estimate.
"""

from __future__ import annotations

import argparse
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import casest  # noqa: E402


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model", help="model file path or bundled model name")
    parser.add_argument("--data", help="CSV with one column per signal and output (header row)")
    parser.add_argument("--stage1-data", help="separate CSV for the stage-1 sweep")
    parser.add_argument("--seed", type=int, default=0, help="seed of simulate() when no --data")
    parser.add_argument("--mode", default="auto", choices=["auto", "reduced", "full", "alternating"])
    parser.add_argument("--covariance", default="hessian", choices=list(casest.uncertainty.COVARIANCE_METHODS))
    parser.add_argument("--json", help="write the Estimate here (atomically)")
    parser.add_argument("--save-data", help="write the data used to this CSV")
    args = parser.parse_args(argv)

    module = casest.load_model_file(args.model)
    model = module.model()
    truth = None
    if args.data:
        data = casest.Dataset.from_csv(model, args.data)
    elif hasattr(module, "simulate"):
        data = module.simulate(args.seed)
        truth = getattr(module, "TRUTH", None)
    else:
        parser.error(f"model file {args.model!r} has no simulate(); pass --data CSV")
    stage1 = casest.Dataset.from_csv(model, args.stage1_data) if args.stage1_data else None
    if args.save_data:
        data.to_csv(args.save_data, units={s.name: s.unit for s in model.signals})

    result = casest.estimate(model, data, stage1_data=stage1, mode=args.mode, covariance=args.covariance)
    print(result.report())
    if truth is not None:
        print("[[Truth]] (simulated data, seed %d)" % args.seed)
        for name, value in result.values.items():
            std = result.stds[name]
            dev = f"{(value - truth[name]) / std:+.2f} std" if std else "std n/a"
            print(f"    {name} = {truth[name]:.8g}   estimate - truth = {value - truth[name]:+.4g} ({dev})")
    if args.json:
        result.to_json(args.json)
        print(f"wrote {args.json}")
    return 0 if result.success else 1


if __name__ == "__main__":
    sys.exit(main())
