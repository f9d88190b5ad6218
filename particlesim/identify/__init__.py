"""Parameter identification: tree robots (consistent parameterisations, regressors, fits, uncertainty, rollouts)
and mechanisms (:mod:`.traces`: constants from measured traces by autodiff through the rollouts)."""

from ._data import (
    KRANG_ARM_GEAR,
    KRANG_ARM_JOINTS,
    KRANG_ARM_KM,
    ArmData,
    DataError,
    arm_data_from_arrays,
    current_limits,
    load_arm_run,
)
from ._base import BaseFit, BaseParameters, base_parameters, fit_base_consistent
from ._fit import (
    CompressedLSQ,
    FitResult,
    compress,
    fit_consistent,
    params_from_theta,
    theta_from_params,
    torque_residuals,
)
from ._uncertainty import BaseUncertainty, base_uncertainty, bootstrap_base, robust_base_uncertainty
from .traces import TraceFit, TraceModel, fit_traces, trace_model
from ._rollout import Windows, fit_rollout, make_windows, rollout_residuals
from ._params import (
    inertia_from_log_cholesky,
    inv_softplus,
    log_cholesky_from_inertia,
    params_from_pseudo_inertia,
    pseudo_inertia,
    softplus,
)
from ._regressor import (
    N_PER_JOINT,
    actuator_columns,
    identifiable_basis,
    model_with_params,
    ordinary_least_squares,
    params_of_model,
    regressor,
    rigid_regressor,
)

__all__ = [
    "KRANG_ARM_GEAR", "KRANG_ARM_JOINTS", "KRANG_ARM_KM", "ArmData", "DataError", "arm_data_from_arrays",
    "current_limits", "load_arm_run", "BaseFit", "BaseParameters", "base_parameters", "fit_base_consistent",
    "CompressedLSQ", "FitResult", "compress", "fit_consistent", "params_from_theta", "theta_from_params",
    "torque_residuals", "BaseUncertainty", "base_uncertainty", "bootstrap_base", "robust_base_uncertainty",
    "TraceFit", "TraceModel", "fit_traces", "trace_model", "Windows", "fit_rollout", "make_windows",
    "rollout_residuals", "inertia_from_log_cholesky", "inv_softplus", "log_cholesky_from_inertia",
    "params_from_pseudo_inertia", "pseudo_inertia", "softplus", "N_PER_JOINT", "actuator_columns",
    "identifiable_basis", "model_with_params", "ordinary_least_squares", "params_of_model", "regressor",
    "rigid_regressor",
]
