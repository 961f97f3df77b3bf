"""What a Monte-Carlo campaign found: per-method rates, the std against the spread, the
conclusions, as JSON, CSV and a Markdown table (:func:`casest.apps.montecarlo.run_campaign`
writes them)."""

from __future__ import annotations

import csv as _csv
import io as _io

import numpy as np

from ..models.modelfile import load_model_file, model_file_hooks


__all__ = ["CORRECT_DISTANCE", "GLOBAL_TOL", "summarize", "runs_csv", "summary_table"]

#: Paper criterion for a "correct" estimate (Tables 1 and 3).
CORRECT_DISTANCE = 0.1
#: Relative tolerance for "reached the global minimum of the ML cost".
GLOBAL_TOL = 1e-6
_METHOD_ORDER = ["proposed", "benchmark1", "benchmark2", "single_stage", "reference"]


def _run_best_cost(record: dict) -> float:
    costs = [m["cost"] for m in record["methods"].values() if m["success"] and m["in_bounds"]]
    return min(costs) if costs else np.inf


def summarize(config, records: list) -> dict:
    """Per-method statistics over the runs (see :func:`run_campaign`)."""
    hooks = model_file_hooks(load_model_file(config.model))
    model = hooks.model()
    truth = model.vector(hooks.truth)
    names = model.parameter_names
    methods = sorted({m for rec in records for m in rec["methods"]}, key=_METHOD_ORDER.index)
    out = {"runs": len(records), "parameters": list(names), "truth": truth.tolist(), "methods": {}}
    for method in methods:
        recs = [r for r in records if method in r["methods"]]
        entry = _method_rates(recs, method, truth)
        stds = np.array([[np.nan if s is None else s for s in r["methods"][method]["std"]] for r in recs])
        if np.isfinite(stds).any():
            thetas = np.array([r["methods"][method]["theta"] for r in recs])
            entry.update(_std_statistics(thetas, stds, truth, names))
        if method == "proposed":
            verdicts = [r["methods"][method].get("verdict") for r in recs]
            entry["verdicts"] = {v: verdicts.count(v) for v in sorted(set(verdicts), key=str)}
        conclusions = [r["methods"][method].get("conclusion") for r in recs]
        if any(c is not None for c in conclusions):
            entry["conclusions"] = {c: conclusions.count(c) for c in sorted(set(conclusions), key=str)}
            entry["trusted_pct"] = 100 * conclusions.count("trusted") / len(recs)
        out["methods"][method] = entry
    return out


def _method_rates(recs: list, method: str, truth: np.ndarray) -> dict:
    """Convergence, correctness and global-minimum rates of one method, and its times."""
    thetas = np.array([r["methods"][method]["theta"] for r in recs])
    success = np.array([r["methods"][method]["success"] for r in recs])
    cost = np.array([r["methods"][method]["cost"] for r in recs])
    inside = np.array([r["methods"][method]["in_bounds"] for r in recs])
    best = np.array([_run_best_cost(r) for r in recs])
    reached = inside & (cost <= best + GLOBAL_TOL * np.maximum(1.0, np.abs(best)))
    correct = np.linalg.norm(thetas - truth, axis=1) < CORRECT_DISTANCE
    seconds = np.array([r["methods"][method]["seconds"] for r in recs])
    return {
        "runs": len(recs),
        "converged_pct": 100 * float(success.mean()),
        "correct_pct": 100 * float(correct.mean()),
        "global_minimum_pct": 100 * float(reached.mean()),
        "median_seconds": float(np.median(seconds)),
        "p95_seconds": float(np.percentile(seconds, 95)),
    }


def _std_statistics(thetas: np.ndarray, stds: np.ndarray, truth: np.ndarray, names) -> dict:
    """Coverage of the reported std and their agreement with the Monte-Carlo spread."""
    available = np.isfinite(stds)
    with np.errstate(invalid="ignore"):
        inside2 = np.abs(thetas - truth) <= 2 * stds
        within3 = np.all(np.abs(thetas - truth) < 3 * stds, axis=1)
    return {
        "coverage_2sigma_pct": {n: (100 * float(inside2[available[:, i], i].mean()) if available[:, i].any() else None)
                                for i, n in enumerate(names)},
        "all_within_3std_pct": 100 * float(within3.mean()),
        "std_available_pct": {n: 100 * float(available[:, i].mean()) for i, n in enumerate(names)},
        "mc_std": {n: float(np.std(thetas[:, i], ddof=1)) if len(thetas) > 1 else None for i, n in enumerate(names)},
        "mean_reported_std": {n: float(np.nanmean(stds[:, i])) if available[:, i].any() else None
                              for i, n in enumerate(names)},
    }


def runs_csv(config, records: list) -> str:
    """One row per run and method: seed, estimates, std, cost, flags, seconds."""
    model = load_model_file(config.model).model()
    names = list(model.parameter_names)
    buf = _io.StringIO()
    w = _csv.writer(buf, lineterminator="\n")
    w.writerow(["run", "seed", "method"] + names + [f"std_{n}" for n in names] + ["cost", "success", "in_bounds", "seconds"])
    for rec in records:
        for method, m in rec["methods"].items():
            w.writerow(
                [rec["run"], rec["seed"], method]
                + [repr(v) for v in m["theta"]]
                + ["" if s is None else repr(s) for s in m["std"]]
                + [repr(m["cost"]), m["success"], m["in_bounds"], f"{m['seconds']:.6f}"]
            )
    return buf.getvalue()


def summary_table(summary: dict) -> str:
    """Markdown table of the summary (one row per method)."""
    names = summary["parameters"]
    head = ("| method | runs | correct % | global min % | converged % | all within 3σ % | "
            + " | ".join(f"2σ cov. {n} %" for n in names) + " | median s | p95 s |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for method, e in summary["methods"].items():
        cov = e.get("coverage_2sigma_pct", {})
        cells = [f"{cov[n]:.1f}" if cov.get(n) is not None else "-" for n in names]
        within = f"{e['all_within_3std_pct']:.1f}" if "all_within_3std_pct" in e else "-"
        lines.append(
            f"| {method} | {e['runs']} | {e['correct_pct']:.1f} | {e['global_minimum_pct']:.1f} | {e['converged_pct']:.1f} | "
            f"{within} | " + " | ".join(cells) + f" | {e['median_seconds']:.4f} | {e['p95_seconds']:.4f} |"
        )
    return "\n".join(lines)
