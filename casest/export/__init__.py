"""Estimators written as dependency-free C for a vehicle's computer: the EKF, IEKF and UKF of a dynamic model
(:func:`export_c`), a static model's recursive least squares (:func:`export_rls_c`) and recursive ML
(:func:`export_rml_c`), and the two-stage estimator over windows of a record (:func:`export_two_stage_c`).
Every export writes its files through one set of rules (:mod:`~casest.export.c_files`: the prefix, the README
sections, nothing replaced that casest did not write). This room stands above every estimator it exports."""

from .batch_c import export_two_stage_c
from .filter_c import EXPORTED_ESTIMATORS, export_c
from .rls_c import export_rls_c
from .rml_c import export_rml_c


__all__ = ["export_c", "EXPORTED_ESTIMATORS", "export_rls_c", "export_rml_c", "export_two_stage_c"]
