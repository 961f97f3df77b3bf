#!/usr/bin/env python3
"""The paper's figures regenerated in one run, with the data behind them beside the tables they show.

    python3 scripts/paper/figures.py [--out out/paper_figures] [--runs 100] [--no-pitot]

Writes to OUT:

- fig2_landscape.png, fig3_predictions.png: scalar example 1 (Eq. 30): Tr[R] over the swept b
  (Fig. 2) and the predicted measurements of ``--runs`` Monte-Carlo estimates (Fig. 3);
- fig4_landscape.png, fig5_predictions.png: scalar example 2 (Eq. 31), the same (Figs. 4, 5);
- fig6_landscape.png, fig7_velocity.png, fig8_airspeed.png and tables.md: the 5-hole Pitot
  calibration (Sec. IV) by ``scripts/paper/pitot_calibration.py`` (unless ``--no-pitot``);
- figures.json: the data of each figure (the landscape's verdict and best candidate, the estimate
  of the first record with its std and R, every run's estimate) and the paper's table values it
  is compared with; comparison.md: that comparison in words.

The records are simulated (seed 0 for the first, then 1, 2, ...), not the paper's noise draws: a
figure's estimate agrees with the paper's table to within the two estimates' combined spread,
``3 sqrt(std_ours^2 + std_paper^2)`` (``tests/test_paper_figures.py``).
"""

from __future__ import annotations

import argparse
import json
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", ".."))

import numpy as np  # noqa: E402

import casest  # noqa: E402
from casest.data.files import atomic_write_text  # noqa: E402

#: the paper's Tables 2 and 4 (estimate, std) and its estimated R, for the scalar examples
PAPER_TABLES = {
    "scalar1": {"table": "Table 2", "estimate": {"a": (0.9512, 0.0507), "b": (0.0812, 0.0182), "c": (0.9415, 0.0360)},
                "R": 0.1199},
    "scalar2": {"table": "Table 4", "estimate": {"a": (0.9980, 0.0474), "b": (0.0546, 0.0059), "c": (0.0895, 0.0351),
                                                 "d": (0.9897, 0.0333)}, "R": 0.1008},
}
#: the figure files of each scalar example: (landscape, predictions)
FIGURES = {"scalar1": ("fig2_landscape.png", "fig3_predictions.png"),
           "scalar2": ("fig4_landscape.png", "fig5_predictions.png")}


def scalar_figure_data(name: str, runs: int, seed: int = 0) -> dict:
    """The data of a scalar example's two figures: the first record's landscape and estimate, and
    ``runs`` estimates (seeds ``seed`` ...) for the predictions."""
    mf = casest.load_model_file(name)
    model = mf.model()
    first = casest.estimate(model, mf.simulate(seed))
    thetas = [first.theta.tolist()] + [casest.estimate(model, mf.simulate(s)).theta.tolist()
                                       for s in range(seed + 1, seed + runs)]
    land = first.landscape
    return {"model": name, "seed": seed, "n_samples": first.n_samples,
            "landscape": {"verdict": land.verdict, "best_xi2": dict(zip(land.nonlinear, land.best_xi2.tolist())),
                          "best_trace_R": float(land.trace_R[land.best_index]), "n_candidates": len(land.trace_R)},
            "estimate": {n: [float(v), float(s)] for n, v, s in zip(first.parameter_names, first.theta, first.std)},
            "R": float(first.R[0]), "success": bool(first.success), "runs_theta": thetas,
            "paper": PAPER_TABLES[name]}


def agreement(figure: dict) -> list:
    """Each quantity of the figure's estimate against the paper's table: (name, ours, paper, limit, holds),
    the limit ``3 sqrt(std_ours^2 + std_paper^2)`` (R: its large-sample std ``R sqrt(2 / N)`` for both)."""
    rows = []
    for name, (paper, paper_std) in figure["paper"]["estimate"].items():
        ours, std = figure["estimate"][name]
        limit = 3 * float(np.hypot(std, paper_std))
        rows.append((name, ours, paper, limit, abs(ours - paper) <= limit))
    R, R_paper, N = figure["R"], figure["paper"]["R"], figure["n_samples"]
    limit = 3 * float(np.hypot(R, R_paper)) * np.sqrt(2 / N)
    rows.append(("R", R, R_paper, limit, abs(R - R_paper) <= limit))
    return rows


def write_scalar_figures(figure: dict, out: str) -> list:
    """The landscape (Fig. 2 or 4) and the predictions (Fig. 3 or 5) of :func:`scalar_figure_data`'s figure."""
    from casest.apps.plots import plot_landscape, plot_predictions

    mf = casest.load_model_file(figure["model"])
    model = mf.model()
    data = mf.simulate(figure["seed"])
    land = casest.sweep(model, data)
    truth = model.vector(mf.TRUTH)[list(casest.separate(model).nonlinear_index)]
    landscape_file, predictions_file = FIGURES[figure["model"]]
    return [plot_landscape(land, os.path.join(out, landscape_file), truth=truth,
                           title=f"{figure['model']}: Tr[R] over the stage-1 sweep (seed {figure['seed']})"),
            plot_predictions(model, data, {"proposed 2-stage": figure["runs_theta"]},
                             os.path.join(out, predictions_file))]


def comparison_lines(figures: list) -> list:
    lines = ["| example | table | quantity | figure's estimate | paper | limit | agrees |", "|---|---|---|---|---|---|---|"]
    for figure in figures:
        for name, ours, paper, limit, holds in agreement(figure):
            lines.append(f"| {figure['model']} | {figure['paper']['table']} | {name} | {ours:.4g} | {paper:.4g} | "
                         f"{limit:.3g} | {'yes' if holds else 'NO'} |")
    return lines


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default=os.path.join(HERE, "..", "..", "out", "paper_figures"))
    parser.add_argument("--runs", type=int, default=100, help="Monte-Carlo estimates drawn in Figs. 3 and 5")
    parser.add_argument("--no-pitot", action="store_true", help="leave out Figs. 6-8 (the Pitot calibration)")
    args = parser.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    figures, paths = [], []
    for name in FIGURES:
        figure = scalar_figure_data(name, args.runs)
        figures.append(figure)
        paths += write_scalar_figures(figure, args.out)
    if not args.no_pitot:
        import pitot_calibration

        pitot_calibration.main(["--out", args.out])
        paths += [os.path.join(args.out, f) for f in ("fig6_landscape.png", "fig7_velocity.png", "fig8_airspeed.png")]
    atomic_write_text(os.path.join(args.out, "figures.json"), json.dumps(figures, indent=1))
    lines = comparison_lines(figures)
    atomic_write_text(os.path.join(args.out, "comparison.md"), "\n".join(lines) + "\n")
    print("\n".join(lines))
    print("\n".join(f"wrote {p}" for p in paths))
    return 0 if all(row[-1] for figure in figures for row in agreement(figure)) else 1


if __name__ == "__main__":
    sys.exit(main())
