"""The ``casest`` command line.

    casest models                      list the bundled model files
    casest solve MODEL [--data CSV]    estimate (stage 1 + stage 2 + uncertainty) and print the report
    casest sweep MODEL [--figure PNG]  stage 1 alone: the Tr[R] landscape and its verdict
    casest mc MODEL --runs N --out DIR a Monte-Carlo campaign against the paper's benchmarks
    casest nist [FILES]                the NIST StRD reference suite
    casest cache [info|clear]          the cache of compiled functions
    casest --version                   the installed version

MODEL is the name of a bundled model (``casest models``) or the path of a model file.
Exit status: 0 success; 1 the estimate did not converge (``success`` False); 2 a user
error (bad file, model or option: one or two lines say what and how to fix it); 3 an
internal error (a traceback and a request to report it); 4 (``solve --strict`` only) the
estimate converged but its conclusion is CAUTION. ``--debug`` shows the traceback of user
errors too.
"""

from __future__ import annotations

import argparse
import contextlib
import glob
import json
import os
import sys
import time
import traceback
import warnings

from ..data.dataset import Dataset, atomic_write_text
from ..errors import CasestError, ModelFileError
from .output_paths import UsageError, check_output_path, stdout_taken
from ..models import DynamicModel, Model
from ..models.modelfile import (
    bundled_data_dir,
    bundled_model_names,
    bundled_models_dir,
    load_model_file,
    slow_user_code_notice,
    model_file_frame,
    model_file_hooks,
)
from ..status import TrustCode


__all__ = ["main", "UsageError"]


class _Parser(argparse.ArgumentParser):
    """argparse with two-line errors (the problem, then where the help is) instead of the usage."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message}\n(see {self.prog} --help)\n")


def _one_line_warning(message, category, filename, lineno, file=None, line=None):
    print(f"casest: warning: {message}", file=file or sys.stderr)


# ----------------------------------------------------------------------------- option types
def _int_at_least(minimum: int, why: str):
    """An argparse type: an integer >= ``minimum`` (``why`` completes the message)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"{value} {why}")
        return value

    return parse


_non_negative_int = _int_at_least(0, "is negative; seeds are integers >= 0")
_positive_int = _int_at_least(1, "must be at least 1")


# ----------------------------------------------------------------------------- models
def cmd_models(args) -> int:
    import ast

    for name in bundled_model_names():
        # the docstring read from the source: listing needs no model built (nor casadi imported)
        path = os.path.join(bundled_models_dir(), f"{name}.py")
        try:
            with open(path, encoding="utf-8") as fh:
                doc = (ast.get_docstring(ast.parse(fh.read())) or "").strip().splitlines()
        except (OSError, SyntaxError, ValueError) as err:  # a broken bundled file must not hide the others
            doc = [f"(cannot be read: {err})"]
        print(f"{name:<20} {doc[0] if doc else ''}")
    return 0


def cmd_cache(args) -> int:
    from .._casadi.numerics import cache_info, clear_cache

    if args.action == "clear":
        print(f"removed {clear_cache()} files from {cache_info()['folder']}")
    else:
        info = cache_info()
        print(f"{info['folder']}: {info['functions']} compiled functions, {info['bytes'] / 2**20:.1f} MiB")
        if info["problem"]:
            print(f"casest cache: the folder cannot be used: {info['problem']}; each process compiles again. Set "
                  "CASEST_CACHE_DIR to a folder of your own", file=sys.stderr)
            return 1
    return 0


# ----------------------------------------------------------------------------- solve / sweep
def _read_data(model, path: str, missing: str) -> Dataset:
    """A CSV file, or a MATLAB file (``.mat``: variables named as the model's columns)."""
    if path.lower().endswith(".mat"):
        return Dataset.from_mat(model, path, missing=missing)
    return Dataset.from_csv(model, path, missing=missing)


def _problem_data(args, module, model):
    """(stage-2 data, stage-1 data or None, truth or None) from --data / --stage1-data / simulate()."""
    hooks = model_file_hooks(module)
    missing = "allow" if getattr(args, "allow_missing", False) else "error"
    if args.data and len(args.data) > 1:  # several experiments sharing the parameters
        return [_read_data(model, path, missing) for path in args.data], None, None
    data, truth = _recorded_or_simulated(args, model, hooks, missing)
    stage1 = _read_data(model, args.stage1_data, "error") if getattr(args, "stage1_data", None) else None
    if stage1 is None and hooks.stage_data is not None and "time" in data.extra:
        stage1, data = hooks.stage_data(data)  # the model file's manoeuvre windows (paper Table 5)
    return data, stage1, truth


def _recorded_or_simulated(args, model, hooks, missing: str) -> tuple:
    """(data, truth): the one file of --data (truth unknown), else the model file's simulate(seed) and truth."""
    if args.data:
        return _read_data(model, args.data[0], missing), None
    if hooks.simulate is None:
        raise UsageError(f"model file {args.model!r} has no simulate(seed); pass --data CSV")
    return hooks.simulate(args.seed), hooks.truth


def _sweep_settings(args, module):
    from ..two_stage.sweep import SweepSettings

    base = model_file_hooks(module).sweep_settings or SweepSettings()
    changes = {}
    if getattr(args, "candidates", None):
        changes["n_candidates"] = args.candidates
    elif getattr(args, "quick", False):
        changes["n_candidates"] = min(base.n_candidates, 200)
    if getattr(args, "design", None):
        changes["design"] = args.design
    if getattr(args, "criterion", None):
        changes["criterion"] = args.criterion
    return SweepSettings(**{**base.__dict__, **changes})


def _fixed_values(items) -> dict:
    """``["a=1.0", ...]`` -> ``{"a": 1.0}``."""
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise UsageError(f"--fix {item!r}: write NAME=VALUE with a number, e.g. --fix a=1.0") from None
        if not sep or not name.strip():
            raise UsageError(f"--fix {item!r}: write NAME=VALUE, e.g. --fix a=1.0")
    names = [item.partition("=")[0].strip() for item in items]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise UsageError(f"--fix gives {repeated} more than once ({list(items)}): give each parameter one value")
    return out


def _noise(text: str | None):
    """``known:z=0.3,y=1`` -> KnownNoise({"z": 0.3, "y": 1.0}); ``None`` -> unknown R."""
    from ..problem.noise import CorrelatedNoise, KnownNoise

    if not text or text == "unknown":
        return None
    if text == "correlated":
        return CorrelatedNoise()
    kind, _, spec = text.partition(":")
    if kind != "known" or not spec:
        raise UsageError(f"--noise {text!r}: write known:OUTPUT=STD[,OUTPUT=STD...] (e.g. --noise known:z=0.3) or "
                         "correlated")
    try:
        pairs = [(k.strip(), float(v)) for k, v in (item.split("=") for item in spec.split(","))]
    except ValueError:
        raise UsageError(f"--noise {text!r}: write known:OUTPUT=STD[,OUTPUT=STD...], e.g. --noise known:z=0.3") from None
    names = [k for k, _ in pairs]
    repeated = sorted({k for k in names if names.count(k) > 1})
    if repeated:
        raise UsageError(f"--noise {text!r} gives the std of {repeated} more than once: give each output one std")
    return KnownNoise(dict(pairs))


def _prepare(args, outputs: dict):
    """Check the output paths, then load the model file, its model and the data."""
    data = args.data or []
    inputs = {"--data" + (f" (file {i + 1})" if len(data) > 1 else ""): path for i, path in enumerate(data)}
    inputs["--stage1-data"] = args.stage1_data
    model_path = args.model if args.model.endswith(".py") else None
    inputs["the model file"] = model_path
    for option, path in outputs.items():
        check_output_path(path, option, {**inputs, **{o: p for o, p in outputs.items() if o != option and p}})
    module = load_model_file(args.model)
    with slow_user_code_notice(f"calling model() of {module.__file__!r}"):
        model = module.model()
    if not isinstance(model, (Model, DynamicModel)):
        raise ModelFileError(f"model() in {module.__file__!r} returned {type(model).__name__}, not a casest.Model or "
                             "casest.DynamicModel; make it return the model it builds")
    data, stage1, truth = _problem_data(args, module, model)
    return module, model, data, stage1, truth


def cmd_solve(args) -> int:
    from ..two_stage.pipeline import estimate

    module, model, data, stage1, truth = _prepare(args, {"--json": args.json, "--save-data": args.save_data,
                                                         "--figure": args.figure, "--html": args.html})
    if args.save_data:
        _save_data(model, data, args.save_data)
    # with an output on standard output (-, /dev/stdout) it alone goes there, everything else to standard error
    taken = stdout_taken(args.json, args.html, args.figure)
    with contextlib.redirect_stdout(sys.stderr) if taken else contextlib.nullcontext():
        result = estimate(model, data, stage1_data=stage1, mode=args.mode, covariance=args.covariance,
                          dof_correction=args.dof_correction,
                          sweep_settings=_sweep_settings(args, module), max_starts=3 if args.quick else 6,
                          fixed=_fixed_values(args.fix), noise=_noise(args.noise), prior_penalty=args.map,
                          separate_noise=not args.shared_noise, progress=not args.quiet)
        print(result.report())
        if truth is not None:
            _print_against_truth(result, truth, args.seed)
        if args.figure:
            print("wrote", _fit_figure(model, data, result, args.figure))
    if args.json:
        result.to_json(args.json)
        print(f"wrote {args.json}", file=sys.stderr if taken else sys.stdout)
    if args.html:
        result.to_html(args.html, model=model, data=data)
        print(f"wrote {args.html}", file=sys.stderr if taken else sys.stdout)
    if not result.success:
        return 1
    return 4 if args.strict and result.conclusion()[0] in (TrustCode.CAUTION, TrustCode.MODEL_ERROR) else 0


def _save_data(model, data, path: str) -> None:
    """--save-data: the stage-2 data as CSV with the model's units."""
    if not isinstance(data, Dataset):
        raise UsageError("--save-data writes one data set; it cannot be combined with several --data")
    units = {s.name: s.unit for s in model.signals}
    units.update(zip(model.output_names, model.output_units))
    data.to_csv(path, units=units)


def _print_against_truth(result, truth: dict, seed: int) -> None:
    """Each estimate against the simulation's truth, in its std."""
    print(f"[[Truth]] (simulated data, seed {seed})")
    for name, value in result.values.items():
        std = result.stds[name]
        dev = f"{(value - truth[name]) / std:+.2f} std" if std else "std n/a"
        print(f"    {name} = {truth[name]:.8g}   estimate - truth = {value - truth[name]:+.4g} ({dev})")


FIT_FIGURE_HELP = ("write measured against estimated outputs here (PNG; a dynamic model: one column per manoeuvre "
                   "and the residual autocorrelation; needs matplotlib: casest[plot])")


def _fit_figure(model, data, result, path: str) -> str:
    """Measured against estimated outputs (:meth:`casest.Estimate.plot_fit`): per manoeuvre with the
    residual autocorrelation (a dynamic model), or over the samples (a static one)."""
    from ..estimation.figures import save_figure

    return save_figure(result.plot_fit(model, data), path)


def cmd_sweep(args) -> int:
    from ..problem.separate import separate
    from ..two_stage.sweep import sweep

    module, model, data, stage1, truth = _prepare(args, {"--figure": args.figure, "--json": args.json})
    if not isinstance(data, Dataset):  # stage 1 on all experiments' samples
        from ..problem.experiments import stack_experiments

        _, data, _ = stack_experiments(model, data, separate_noise=False)
    fixed = _fixed_values(args.fix)
    if fixed:
        model = model.with_fixed(fixed)
    land = sweep(model, stage1 or data, separate(model), _sweep_settings(args, module), progress=not args.quiet)
    taken = stdout_taken(args.json, args.figure)
    print(land.summary(), file=sys.stderr if taken else sys.stdout)
    if args.json:
        atomic_write_text(args.json, json.dumps(land.to_dict(), indent=1) + "\n")
        print(f"wrote {args.json}", file=sys.stderr if taken else sys.stdout)
    if args.figure:
        from .plots import plot_landscape

        xi2_truth = None
        if truth is not None and land.nonlinear:
            xi2_truth = [truth[n] for n in land.nonlinear]
        print("wrote", plot_landscape(land, args.figure, truth=xi2_truth, title=f"{model.name}: stage 1"),
              file=sys.stderr if taken else sys.stdout)
    return 0


# ----------------------------------------------------------------------------- mc
def _campaign_figures(config, out: str) -> list:
    from ..problem.separate import separate
    from ..two_stage.sweep import sweep
    from .plots import plot_landscape, plot_predictions

    hooks = model_file_hooks(load_model_file(config.model))
    model = hooks.model()
    data = hooks.simulate(config.first_seed)
    stage1 = hooks.stage_data(data)[0] if hooks.stage_data is not None else data
    land = sweep(model, stage1, settings=hooks.sweep_settings)
    part = separate(model)
    truth = model.vector(hooks.truth)[list(part.nonlinear_index)]
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


def cmd_mc(args) -> int:
    from .montecarlo import CampaignConfig, run_campaign, summary_table

    module = load_model_file(args.model)
    model_file_hooks(module).require("simulate", "truth", purpose="a campaign")
    noise = _noise(args.noise)
    if noise is not None and not hasattr(noise, "std"):
        raise UsageError("casest mc --noise takes known:OUT=STD,... (a known noise std per output)")
    config = CampaignConfig(model=os.path.abspath(module.__file__), first_seed=args.first_seed,
                            reference_starts=args.reference_starts, covariance=args.covariance,
                            dof_correction=args.dof_correction,
                            noise=dict(noise.std) if noise is not None else None,
                            fixed=_fixed_values(args.fix) or None)
    t0 = time.perf_counter()
    summary = run_campaign(config, args.runs, args.out, workers=args.workers, scheduler=args.scheduler,
                           progress=not args.quiet, jit=args.jit)
    wall = time.perf_counter() - t0
    covariance = config.covariance + (" with the degrees-of-freedom correction" if config.dof_correction else "")
    text = (f"{os.path.basename(config.model)}: {summary['runs']} runs, covariance {covariance}, "
            f"{config.reference_starts}-start reference; this invocation took {wall:.1f} s\n\n{summary_table(summary)}\n")
    text += "".join(_method_lines(method, e, summary["parameters"]) for method, e in summary["methods"].items())
    atomic_write_text(os.path.join(args.out, "summary.md"), text + "\n")
    print(text)
    if args.figures:
        for path in _campaign_figures(config, args.out):
            print("wrote", path)
    return 0


def _method_lines(method: str, e: dict, parameters) -> str:
    """A campaign method's spread against its reported std, stage-1 verdicts and conclusions."""
    text = ""
    if "mc_std" in e:
        pairs = ", ".join(f"{n} {e['mc_std'][n]:.4g}/{e['mean_reported_std'][n]:.4g}" for n in parameters
                          if e["mean_reported_std"][n] is not None)
        text += f"\n{method}: MC std / mean reported std: {pairs}"
    if "verdicts" in e:
        text += f"\n{method}: stage-1 verdicts {e['verdicts']}"
    if "conclusions" in e:
        text += f"\n{method}: conclusions {e['conclusions']} (trust it in {e['trusted_pct']:.1f} % of the runs)"
    return text


# ----------------------------------------------------------------------------- nist
def cmd_nist(args) -> int:
    from .nist import protocol_report

    files = args.files or sorted(glob.glob(bundled_data_dir("nist_strd", "*.dat")))
    if not files:
        raise UsageError("no NIST files given, and none are bundled with this installation")
    return 0 if protocol_report(files, args.starts, separable=not args.files) else 1


# ----------------------------------------------------------------------------- parser
def _add_mc_parser(sub, common, covariance_methods) -> None:
    """``casest mc``: a Monte-Carlo campaign and its options."""
    p = sub.add_parser("mc", parents=[common], help="Monte-Carlo campaign against the paper's benchmarks")
    p.add_argument("model", help="bundled model name or model file path (needs simulate() and TRUTH)")
    p.add_argument("--runs", type=_positive_int, default=100, help="number of runs (seeds first-seed ...)")
    p.add_argument("--workers", type=_positive_int, default=os.cpu_count() or 1,
                   help="local worker processes (default: one per core)")
    p.add_argument("--out", required=True, help="output folder (a re-run with the same folder resumes)")
    p.add_argument("--scheduler", help="Dask distributed scheduler address, e.g. tcp://127.0.0.1:8786")
    p.add_argument("--first-seed", type=_non_negative_int, default=0, help="seed of the first run (default 0)")
    p.add_argument("--reference-starts", type=_positive_int, default=32,
                   help="starts of the multi-start reference that defines the global minimum (default 32)")
    p.add_argument("--covariance", default="hessian", choices=list(covariance_methods),
                   help="how the proposed estimator's std are computed (default: the inverse exact Hessian)")
    p.add_argument("--dof-correction", action="store_true",
                   help="multiply the covariance by N m / (N m - p) (NIST's s^2 = RSS / (n - p))")
    p.add_argument("--figures", action="store_true", help="write landscape.png and predictions.png")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--jit", action="store_true", help="compile the stage-2 sums for every N")
    p.add_argument("--noise", metavar="known:OUT=STD,...", help="give the proposed estimator this known noise std "
                   "(e.g. a wrong one, to check its conclusion line); the benchmarks then do not run")
    p.add_argument("--fix", action="append", default=[], metavar="NAME=VALUE", help="hold a parameter at a value in "
                   "the proposed estimator (repeatable); the benchmarks then do not run")
    p.set_defaults(func=cmd_mc)


def build_parser() -> argparse.ArgumentParser:
    from ..options import CovarianceMethod, choices

    COVARIANCE_METHODS = choices(CovarianceMethod)

    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                        help="show the full traceback of errors")
    parser = _Parser(prog="casest", description=__doc__, parents=[common],
                     formatter_class=argparse.RawDescriptionHelpFormatter)
    from .. import __version__

    parser.add_argument("--version", action="version", version=f"casest {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True

    sub.add_parser("models", parents=[common], help="list the bundled model files").set_defaults(func=cmd_models)

    def problem_options(p):
        p.add_argument("model", help="bundled model name (casest models) or model file path")
        p.add_argument("--data", action="append", help="CSV (header row, units in brackets) or MATLAB .mat file, a "
                       "column per signal and output; repeat for experiments that share the parameters")
        p.add_argument("--allow-missing", action="store_true", help="an empty or NaN output field means "
                       "'not measured' (default: an error)")
        p.add_argument("--shared-noise", action="store_true", help="with several --data: one noise R for all "
                       "experiments (default: one per experiment)")
        p.add_argument("--stage1-data", help="separate CSV for the stage-1 sweep")
        p.add_argument("--seed", type=_non_negative_int, default=0, help="seed of the model file's simulate() "
                       "when no --data is given")
        p.add_argument("--candidates", type=_positive_int, help="stage-1 candidates (default: the model file's or 2000)")
        p.add_argument("--design", choices=["auto", "grid", "sobol", "random"], help="stage-1 design")
        p.add_argument("--criterion", choices=["trace", "likelihood"],
                       help="stage-1 ranking: Tr[R] (the paper's) or the profile likelihood (channels in different units)")
        p.add_argument("--quick", action="store_true", help="at most 200 stage-1 candidates and 3 stage-2 starts")
        p.add_argument("--fix", action="append", default=[], metavar="NAME=VALUE",
                       help="hold a parameter at a value (repeatable), e.g. --fix a=1.0")
        p.add_argument("--noise", metavar="known:OUT=STD,...|correlated", help="known noise std per output, e.g. "
                       "--noise known:z=0.3, or 'correlated' for a full unknown R (default: R unknown, diagonal)")
        p.add_argument("--map", action="store_true", help="Gaussian priors also enter the cost as penalties (MAP)")

    p = sub.add_parser("solve", parents=[common], help="estimate and print the report")
    problem_options(p)
    p.add_argument("--mode", default="auto", choices=["auto", "paper", "reduced", "full", "alternating"],
                   help="stage-2 mode (default auto: reduced when there are linear and nonlinear parameters)")
    p.add_argument("--covariance", default="hessian", choices=list(COVARIANCE_METHODS),
                   help="how the std are computed (default: the inverse exact Hessian)")
    p.add_argument("--dof-correction", action="store_true",
                   help="multiply the covariance by N m / (N m - p) (NIST's s^2 = RSS / (n - p))")
    p.add_argument("--json", help="write the Estimate here (atomically; - for standard output, the report then on "
                   "standard error)")
    p.add_argument("--quiet", action="store_true", help="no stage lines or progress bar on standard error")
    p.add_argument("--html", help="write the estimate as one self-contained HTML page here (atomically)")
    p.add_argument("--save-data", help="write the data used to this CSV")
    p.add_argument("--figure", help=FIT_FIGURE_HELP)
    p.add_argument("--strict", action="store_true", help="exit with status 4 when the estimate converged but the "
                   "conclusion is CAUTION (a failed residual test, no std, no global evidence, an equal-cost alias)")
    p.set_defaults(func=cmd_solve)

    p = sub.add_parser("sweep", parents=[common], help="stage 1 alone: landscape, verdict, figure")
    problem_options(p)
    p.add_argument("--figure", help="write the Tr[R] landscape here (PNG; needs matplotlib: casest[plot])")
    p.add_argument("--json", help="write the landscape here (JSON; - for standard output)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_sweep)

    _add_mc_parser(sub, common, COVARIANCE_METHODS)

    p = sub.add_parser("nist", parents=[common], help="NIST StRD suite (bundled files from both starts)")
    p.add_argument("files", nargs="*", help="NIST .dat files (default: the bundled twelve)")
    p.add_argument("--starts", nargs="+", type=int, choices=[1, 2], default=[1, 2],
                   help="the NIST starting points to run from (default both)")
    p.set_defaults(func=cmd_nist)

    from .export_cli import add_export_parser

    add_export_parser(sub, common)
    _add_cache_parser(sub, common)
    return parser


def _add_cache_parser(sub, common) -> None:
    """``casest cache``: the compile cache's folder and contents, or emptying it."""
    p = sub.add_parser("cache", parents=[common], help="the cache of compiled functions: info or clear")
    p.add_argument("action", choices=["info", "clear"], nargs="?", default="info",
                   help="info (default): where the cache is and what it holds; clear: empty it")
    p.set_defaults(func=cmd_cache)


def main(argv=None) -> int:
    """Run the command line; returns the exit status (see the module docstring)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    debug = getattr(args, "debug", False)
    previous = warnings.showwarning
    if not debug:
        warnings.showwarning = _one_line_warning  # notes for a terminal, not source lines
    try:
        return _run(args, debug)
    finally:
        warnings.showwarning = previous


def _run(args, debug: bool) -> int:
    """The command, with user errors in one or two lines and internal errors with a traceback."""
    try:
        return args.func(args)
    except BrokenPipeError:  # the reader went away (casest models | head): nothing to report
        sys.stderr = open(os.devnull, "w")
        return 0
    except (CasestError, OSError) as err:
        if debug:
            raise
        _print_user_error(args.command, err)
        return 2
    except KeyboardInterrupt:
        print(f"casest {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as err:  # the user's model file, or an internal error
        frame = model_file_frame(err.__traceback__)
        if frame is not None:  # raised while the user's model file ran: theirs to fix
            if debug:
                raise
            print(f"casest {args.command}: error: the model file {frame.filename!r} raised "
                  f"{type(err).__name__} at line {frame.lineno} (in {frame.name}): {err}", file=sys.stderr)
            print("(fix the model file; run with --debug for the traceback)", file=sys.stderr)
            return 2
        traceback.print_exc()
        print(f"casest {args.command}: internal error. This is a bug in casest; please report it with the command "
              "line, this traceback and, if you can, the data.", file=sys.stderr)
        return 3


def _print_user_error(command: str, err: Exception) -> None:
    """A casest error or an OS error in one line, and where to see the traceback (not for usage errors)."""
    message = str(err) if not isinstance(err, OSError) or not err.filename else f"{err.strerror}: {err.filename!r}"
    print(f"casest {command}: error: {message}", file=sys.stderr)
    if not isinstance(err, UsageError):
        print("(run with --debug for the traceback)", file=sys.stderr)


if __name__ == "__main__":
    sys.exit(main())
