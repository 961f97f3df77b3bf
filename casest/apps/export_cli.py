"""``casest export-c``: a model file's online estimator as C (:func:`casest.export.filter_c.export_c`)."""

from __future__ import annotations

import numpy as np

from ..models import OptionError, load_model_file
from ..models.modelfile import slow_user_code_notice
from ..models.dynamic import DynamicModel

__all__ = ["add_export_parser", "cmd_export_c"]


def add_export_parser(sub, common) -> None:
    """The ``export-c`` subcommand and its options.

    Parameters
    ----------
    sub : argparse subparsers
    common : argparse.ArgumentParser
        The options every command takes.

    Returns
    -------
    None
    """
    from ..options import ExportedEstimator, choices

    p = sub.add_parser("export-c", parents=[common],
                       help="write an online estimator as dependency-free C (source, header, README): a dynamic "
                       "model's EKF, IEKF or UKF, a static model's recursive least squares or recursive ML")
    p.add_argument("model", help="bundled model name or model file path")
    p.add_argument("--estimator", choices=list(choices(ExportedEstimator)), default="ekf",
                   help="ekf (default), iekf (iterated measurement update), ukf (unscented): a DynamicModel; "
                   "rls (recursive least squares of the linear parameters), rml (recursive ML): a static Model")
    p.add_argument("--out", required=True, help="output folder (created if missing)")
    p.add_argument("--name", help="the C prefix of every symbol (default casest_<model>_<estimator>)")
    p.add_argument("--force", action="store_true",
                   help="replace files of the export's names that casest did not write (they are listed); without "
                   "it such files stop the export. README.md keeps the sections of other exports either way")
    p.set_defaults(func=cmd_export_c)


def cmd_export_c(args) -> int:
    """Write the files and print their paths.

    Parameters
    ----------
    args : argparse.Namespace

    Returns
    -------
    int
        The exit status (0).
    """
    from ..export.filter_c import export_c
    from ..export.rls_c import export_rls_c
    from ..export.rml_c import export_rml_c
    from ..filters.ekf import ExtendedKalmanFilter
    from ..filters.unscented import UnscentedKalmanFilter

    module = load_model_file(args.model)
    with slow_user_code_notice(f"calling model() of {module.__file__!r}"):
        model = module.model()
    static_writers = {"rls": (export_rls_c, "recursive least squares"), "rml": (export_rml_c, "recursive ML")}
    if args.estimator in static_writers:
        writer, what = static_writers[args.estimator]
        if isinstance(model, DynamicModel):
            raise OptionError(f"{args.model}: --estimator {args.estimator} writes the {what} of a static "
                              "casest.Model; for a DynamicModel use ekf, iekf or ukf")
        return _written(writer(model, args.out, args.name, force=args.force))
    if not isinstance(model, DynamicModel):
        raise OptionError(f"{args.model}: export-c writes the filters of a casest.DynamicModel; this model file's "
                          f"model() is a {type(model).__name__} (its recursive estimators: --estimator rls or rml)")
    n = model.n_states
    # the structure only: theta, the noise and the start are the C code's init arguments
    structure = (model, model.nominal, np.zeros(n), np.ones(model.n_outputs), np.eye(n))
    flt = UnscentedKalmanFilter(*structure) if args.estimator == "ukf" else \
        ExtendedKalmanFilter(*structure, iterated=args.estimator == "iekf")
    return _written(export_c(flt, args.out, args.name, force=args.force))


def _written(paths: dict) -> int:
    """Print the files written and those ``--force`` replaced; the exit status (0)."""
    for key in ("header", "source", "readme"):
        print("wrote", paths[key])
    for path in paths.replaced:
        print("replaced (casest had not written it):", path)
    return 0
