#!/usr/bin/env python3
"""Monte-Carlo comparison of the two-stage estimator with the paper's benchmarks.

    python3 scripts/monte_carlo.py MODEL --runs N --workers W --out DIR
            [--scheduler ADDRESS] [--first-seed S] [--reference-starts K]
            [--covariance hessian|hessian-dof|gauss-newton|gauss-newton-dof] [--figures] [--quiet] [--jit]

Each run draws new noise (seed first_seed + run) and estimates with the proposed
estimator, Benchmark 1 (random start, same box; when the model file has
BENCHMARK1_STARTS), Benchmark 2 (Haupt/Kasdin; change_of_variables()), the single-stage
NLP (SINGLE_STAGE_START) and a K-start reference. A model file's stage_data(data) splits
each record into stage-1 and stage-2 data (paper Table 5). DIR receives config.json,
runs.jsonl (one line per finished run: a re-run with the same DIR resumes), summary.json,
runs.csv and summary.md; --figures adds the landscape and prediction PNGs.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import casest  # noqa: E402
from casest.data import atomic_write_text  # noqa: E402
from casest.montecarlo import CampaignConfig, run_campaign, summary_table  # noqa: E402


def figures(config: CampaignConfig, out: str) -> list:
    from casest.plots import plot_landscape, plot_predictions

    module = casest.load_model_file(config.model)
    model = module.model()
    data = module.simulate(config.first_seed)
    stage1 = module.stage_data(data)[0] if hasattr(module, "stage_data") else data
    land = casest.sweep(model, stage1, settings=getattr(module, "SWEEP_SETTINGS", None))
    part = casest.separate(model)
    truth = model.vector(module.TRUTH)[list(part.nonlinear_index)]
    paths = [plot_landscape(land, os.path.join(out, "landscape.png"), truth=truth,
                            title=f"{model.name}: Tr[R] over the stage-1 sweep (seed {config.first_seed})")]
    thetas = {}
    with open(os.path.join(out, "runs.jsonl"), encoding="utf-8") as fh:
        for line in fh:
            rec = json.loads(line)
            for method, m in rec["methods"].items():
                if method != "reference":
                    thetas.setdefault(method, []).append(m["theta"])
    if model.n_signals == 1:  # predicted outputs over the signal, as in the paper's Figs. 3 and 5
        paths.append(plot_predictions(model, data, thetas, os.path.join(out, "predictions.png")))
    return paths


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model", help="model file path or bundled model name")
    parser.add_argument("--runs", type=int, default=100)
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--out", required=True)
    parser.add_argument("--scheduler", help="Dask distributed scheduler address, e.g. tcp://127.0.0.1:8786")
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--reference-starts", type=int, default=32)
    parser.add_argument("--covariance", default="hessian", choices=list(casest.uncertainty.COVARIANCE_METHODS))
    parser.add_argument("--figures", action="store_true", help="write landscape.png and predictions.png")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("--jit", action="store_true", help="compile the stage-2 sums for every N (default: from N = 2000 when a C compiler is found)")
    args = parser.parse_args(argv)

    module = casest.load_model_file(args.model)
    for needed in ("simulate", "TRUTH"):
        if not hasattr(module, needed):
            parser.error(f"model file {args.model!r} lacks {needed}, which a campaign needs")
    config = CampaignConfig(
        model=os.path.abspath(module.__file__),
        first_seed=args.first_seed,
        reference_starts=args.reference_starts,
        covariance=args.covariance,
    )
    t0 = time.perf_counter()
    summary = run_campaign(config, args.runs, args.out, workers=args.workers, scheduler=args.scheduler,
                           progress=not args.quiet, jit=args.jit)
    wall = time.perf_counter() - t0
    table = summary_table(summary)
    text = (f"{os.path.basename(config.model)}: {summary['runs']} runs, covariance {config.covariance}, "
            f"{config.reference_starts}-start reference; this invocation took {wall:.1f} s\n\n{table}\n")
    for method, e in summary["methods"].items():
        if "mc_std" in e:
            pairs = ", ".join(f"{n} {e['mc_std'][n]:.4g}/{e['mean_reported_std'][n]:.4g}" for n in summary["parameters"]
                              if e["mean_reported_std"][n] is not None)
            text += f"\n{method}: MC std / mean reported std: {pairs}"
        if "verdicts" in e:
            text += f"\n{method}: stage-1 verdicts {e['verdicts']}"
    atomic_write_text(os.path.join(args.out, "summary.md"), text + "\n")
    print(text)
    if args.figures:
        for p in figures(config, args.out):
            print("wrote", p)
    return 0


if __name__ == "__main__":
    sys.exit(main())
