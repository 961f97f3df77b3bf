"""Design the 5-hole Pitot calibration flight (paper Sec. IV) before flying it.

Candidate manoeuvres: wind circles at 10, 20, 30 and 40 deg of bank (24.2 s each), the
pushover-pullup, the four multisines, the two pitch chirps, the yaw chirp and the rudder
doublet of Table 5, each from a noise-free simulated flight. The budget is the flight time
of the paper's stage-2 schedule (the Table 5 windows its estimates come from, each flown
once: 156.5 s, plus 5 s to set up each of its 8 manoeuvres: 196.5 s; every repetition of a designed
manoeuvre pays the same set-up). `casest.design_experiment` chooses how often to fly each candidate for a
D-optimal design, robust over four wind guesses (the wind is not known before the flight:
4.5 m/s from N, E, S, W) with the calibration parameters at their nominal zeros.

Then a Monte-Carlo check: for each run, a fresh noisy flight of the paper's schedule
(stage 1 on the Table 5 stage-1 windows, stage 2 on the stage-2 windows, as the paper)
and of the designed schedule (every repetition from its own noisy flight; both stages on
the designed data), each estimated by `casest.estimate`. Printed per parameter: the
predicted std (Cramer-Rao, at the truth) and the Monte-Carlo std of both schedules.

    python3 scripts/paper/design_pitot.py [--runs 30] [--out out/design_pitot]

Writes ``design_pitot.json`` (atomically) and, with matplotlib, ``design_pitot.png``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

import casest  # noqa: E402
from casest.design.information import information_matrix  # noqa: E402
from casest.data import atomic_write_text  # noqa: E402
from casest.apps.sim.flight import MANEUVERS  # noqa: E402

CIRCLE_WINDOW = (384.0, 408.2)  # Table 5's first wind circle
CIRCLE_BANKS = (10, 20, 30, 40)  # deg
WIND_GUESSES = [(4.5, 0.0), (0.0, 4.5), (-4.5, 0.0), (0.0, -4.5)]  # (W_N, W_E), m/s


def load_module():
    return casest.load_model_file(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "models",
                                               "pitot5hole.py"))


def window(data, t0: float, t1: float):
    t = data.column("time")
    return data.subset((t >= t0) & (t <= t1))


def candidate_windows() -> dict:
    """name -> (t0, t1, circle bank or None) of every candidate manoeuvre."""
    out = {f"wind circle {b} deg": (*CIRCLE_WINDOW, b) for b in CIRCLE_BANKS}
    for name, t0, t1, _ in MANEUVERS:
        if not name.startswith("wind circle"):
            out[name] = (t0, t1, None)
    return out


def paper_schedule() -> dict:
    """The paper's stage-2 data: every Table 5 stage-2 window once."""
    return {name: 1 for name, _, _, stage in MANEUVERS if stage == 2}


def candidates(module, seed: int, noise: bool, names=None) -> dict:
    """name -> Dataset of each candidate window, each from its own short flight of this seed
    (the flight starts 5 s before the window; the seed varies speed, phases and heading)."""
    wins = candidate_windows()
    names = list(wins) if names is None else list(names)
    out = {}
    for k, name in enumerate(names):
        t0, t1, bank = wins[name]
        flight = module.simulate(seed * 97 + k, noise=noise, t_start=t0 - 5.0, t_end=t1 + 0.1,
                                 circle_banks=None if bank is None else (bank, -bank))
        out[name] = window(flight, t0, t1)
    return out


def schedule_data(module, schedule: dict, seed: int):
    """One noisy realisation of a schedule: each repetition from its own flight."""
    parts = []
    for rep in range(max(schedule.values())):
        names = [n for n, k in schedule.items() if k > rep]
        parts += list(candidates(module, seed * 100 + rep, True, names).values())
    model = module.model()
    return casest.Dataset.from_arrays(model, np.vstack([p.signals for p in parts]), np.vstack([p.outputs for p in parts]))


def predicted_cov(model, cands: dict, schedule: dict, theta, R) -> np.ndarray:
    F = sum(k * information_matrix(model, cands[n], theta, R) for n, k in schedule.items())
    return np.linalg.inv(F)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=30, help="Monte-Carlo flights per schedule (default 30)")
    parser.add_argument("--criterion", default="D", choices=["D", "A", "E"])
    parser.add_argument("--setup", type=float, default=5.0,
                        help="seconds to set up each manoeuvre, counted in the budget (default 5)")
    parser.add_argument("--out", default=os.path.join("out", "design_pitot"))
    args = parser.parse_args(argv)
    t_start = time.perf_counter()
    module = load_module()
    model = module.model()
    R = np.array(module.NAV_NOISE_STD) ** 2
    cands = candidates(module, 0, noise=False)
    wins = candidate_windows()
    durations = {n: wins[n][1] - wins[n][0] + args.setup for n in cands}
    paper = paper_schedule()
    budget = sum(durations[n] * k for n, k in paper.items())  # the paper's flight time, set-ups included
    guesses = [{**{n: 0.0 for n in model.parameter_names}, "W_N": wn, "W_E": we} for wn, we in WIND_GUESSES]
    t0 = time.perf_counter()
    design = casest.design_experiment(model, cands, guesses, R, budget, durations, criterion=args.criterion,
                                      robust="average")
    design_seconds = time.perf_counter() - t0
    print(design.report())
    print(f"design: {design_seconds:.2f} s (IPOPT and rounding; the candidates' information included)")
    designed = design.schedule()
    truth = model.vector(module.TRUTH)
    pred = {"paper": np.sqrt(np.diag(predicted_cov(model, cands, paper, truth, R))),
            "designed": np.sqrt(np.diag(predicted_cov(model, cands, designed, truth, R)))}

    estimates = {"paper": [], "designed": []}
    failures = {"paper": 0, "designed": 0}
    for run in range(args.runs):
        flight = module.simulate(1000 + run)
        stage1, stage2 = module.stage_data(flight)
        est = casest.estimate(model, stage2, stage1_data=stage1, sweep_settings=module.SWEEP_SETTINGS)
        (estimates["paper"] if est.success else []).append(est.theta)
        failures["paper"] += not est.success
        data = schedule_data(module, designed, 2000 + run)
        est = casest.estimate(model, data, sweep_settings=module.SWEEP_SETTINGS)
        (estimates["designed"] if est.success else []).append(est.theta)
        failures["designed"] += not est.success
        print(f"run {run + 1}/{args.runs}", end="\r", flush=True)
    print()
    mc = {k: np.std(np.array(v), axis=0, ddof=1) for k, v in estimates.items()}
    bias = {k: (np.mean(np.array(v), axis=0) - truth) / pred[k] for k, v in estimates.items()}

    header = (f"{'parameter':<13} {'paper pred.':>11} {'paper MC':>9} {'MC/pred':>7} {'designed pred.':>14} "
              f"{'designed MC':>11} {'MC/pred':>7} {'designed/paper MC':>17}")
    print(f"\nbudget {budget:.1f} s; designed schedule: {designed} "
          f"({float(design.rounded @ design.durations):.1f} s)")
    print(f"Monte Carlo: {args.runs} flights per schedule; failures: paper {failures['paper']}, designed "
          f"{failures['designed']}")
    print(header)
    for i, name in enumerate(model.parameter_names):
        print(f"{name:<13} {pred['paper'][i]:11.4g} {mc['paper'][i]:9.4g} {mc['paper'][i] / pred['paper'][i]:7.2f} "
              f"{pred['designed'][i]:14.4g} {mc['designed'][i]:11.4g} {mc['designed'][i] / pred['designed'][i]:7.2f} "
              f"{mc['designed'][i] / mc['paper'][i]:17.2f}")
    # a sample std of n Gaussian estimates: (n-1) s^2 / sigma^2 ~ chi-square(n-1)
    from scipy.special import chdtri

    n_mc = min(len(v) for v in estimates.values())
    band = [np.sqrt(chdtri(n_mc - 1, q) / (n_mc - 1)) for q in (0.975, 0.025)]
    print(f"MC/pred from sampling alone (n = {n_mc}): 95 % within [{band[0]:.2f}, {band[1]:.2f}]")
    logdet = {k: float(np.sum(np.log(pred[k] ** 2))) for k in pred}
    det_mc = {k: float(np.linalg.slogdet(np.cov(np.array(v).T))[1]) for k, v in estimates.items()}
    print(f"ln det of the covariance: predicted paper {np.linalg.slogdet(predicted_cov(model, cands, paper, truth, R))[1]:.2f}, "
          f"designed {np.linalg.slogdet(predicted_cov(model, cands, designed, truth, R))[1]:.2f}; "
          f"Monte Carlo paper {det_mc['paper']:.2f}, designed {det_mc['designed']:.2f}")
    print(f"wall {time.perf_counter() - t_start:.0f} s")

    os.makedirs(args.out, exist_ok=True)
    result = {
        "budget_s": budget, "criterion": args.criterion, "wind_guesses": WIND_GUESSES,
        "design": {"repeats": dict(zip(design.names, design.repeats.tolist())), "schedule": designed,
                   "success": design.success, "seconds": design_seconds},
        "paper_schedule": paper, "runs": args.runs, "failures": failures,
        "parameters": list(model.parameter_names),
        "predicted_std": {k: v.tolist() for k, v in pred.items()},
        "monte_carlo_std": {k: v.tolist() for k, v in mc.items()},
        "mean_error_in_predicted_std": {k: v.tolist() for k, v in bias.items()},
        "ln_det_monte_carlo": det_mc, "sum_ln_var_predicted": logdet,
    }
    atomic_write_text(os.path.join(args.out, "design_pitot.json"), json.dumps(result, indent=2))
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib not installed (pip install casest[plots]): no figure")
        return result
    fig, ax = plt.subplots(figsize=(9, 4))
    x = np.arange(model.n_parameters)
    ref = pred["paper"]
    for k, (key, kind) in enumerate([("paper", "pred"), ("paper", "mc"), ("designed", "pred"), ("designed", "mc")]):
        values = (pred if kind == "pred" else mc)[key] / ref
        ax.bar(x + (k - 1.5) * 0.2, values, 0.2, label=f"{key} {'predicted' if kind == 'pred' else 'Monte Carlo'}",
               hatch="" if kind == "pred" else "//", color="C0" if key == "paper" else "C1", alpha=0.6 + 0.4 * (kind == "mc"))
    ax.set_xticks(x, model.parameter_names, rotation=30)
    ax.set_ylabel("std / paper's predicted std")
    ax.set_title(f"Pitot calibration: designed ({args.criterion}-optimal) vs paper's schedule, {budget:.0f} s each")
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = os.path.join(args.out, "design_pitot.png")
    fig.savefig(path + ".tmp.png", dpi=120)
    os.replace(path + ".tmp.png", path)
    print(f"figure: {path}")
    return result


if __name__ == "__main__":
    main()
