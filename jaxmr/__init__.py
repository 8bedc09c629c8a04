"""jaxmr: differentiable physics of magnetorheological dampers and brakes in JAX.

The public names below are imported when one of them is first used (PEP 562), not by
`import jaxmr`: importing JAX, diffrax and equinox takes seconds, and `jaxmr --help`,
`import jaxmr.data` for a file or a script that only reads `jaxmr.__version__` should
not pay for it. The first use of any public name imports them all, as an eager
`__init__` would. The imports under `TYPE_CHECKING` are the one list of the public API:
pyright and the documentation's griffe read them as written, and `__getattr__` reads
them from this file's syntax tree.
"""

import ast
import importlib
import warnings
from typing import TYPE_CHECKING

from ._version import __version__ as __version__

if TYPE_CHECKING:
    from ._channel import ChannelDelay as ChannelDelay
    from ._closed_loop import (
        Sampling as Sampling,
        SystemSolution as SystemSolution,
        free_decay as free_decay,
        simulate_system as simulate_system,
    )
    from ._control import (
        AbstractController as AbstractController,
        AccelerationDrivenDamper as AccelerationDrivenDamper,
        Backstepping as Backstepping,
        ClippedOptimal as ClippedOptimal,
        ConstantCurrent as ConstantCurrent,
        ContinuousClippedOptimal as ContinuousClippedOptimal,
        CurrentSchedule as CurrentSchedule,
        DamperObserver as DamperObserver,
        DamperPlant as DamperPlant,
        ForceFeedback as ForceFeedback,
        Groundhook as Groundhook,
        Hybrid as Hybrid,
        LyapunovController as LyapunovController,
        ObserverBasedController as ObserverBasedController,
        OnOffGroundhook as OnOffGroundhook,
        OnOffSkyhook as OnOffSkyhook,
        PowerDrivenDamper as PowerDrivenDamper,
        Sensor as Sensor,
        Sensors as Sensors,
        Skyhook as Skyhook,
        VelocityEstimator as VelocityEstimator,
        feature_scales as feature_scales,
        realistic_sensors as realistic_sensors,
        replay as replay,
        with_temperature as with_temperature,
    )
    from ._current_dynamics import (
        AbstractCurrentDynamics as AbstractCurrentDynamics,
        FirstOrderLag as FirstOrderLag,
    )
    from ._current_law import (
        AbstractCurrentLaw as AbstractCurrentLaw,
        ConstantLaw as ConstantLaw,
        ExponentialLaw as ExponentialLaw,
        LinearLaw as LinearLaw,
        PolynomialLaw as PolynomialLaw,
        SaturatingLaw as SaturatingLaw,
        TableLaw as TableLaw,
    )
    from ._damper import (
        Damper as Damper,
        with_fitted_range as with_fitted_range,
    )
    from ._export import (
        export_c as export_c,
        export_stablehlo as export_stablehlo,
    )
    from ._fitted_range import (
        FittedRange as FittedRange,
        OutsideFittedRange as OutsideFittedRange,
    )
    from ._hysteresis import (
        AbstractHysteresis as AbstractHysteresis,
        Bingham as Bingham,
        BoucWen as BoucWen,
        BoucWenBaberNoori as BoucWenBaberNoori,
        Dahl as Dahl,
        LuGre as LuGre,
        NormalizedBoucWen as NormalizedBoucWen,
        ShearThinningSpencer as ShearThinningSpencer,
        Spencer as Spencer,
    )
    from ._identify import (
        Design as Design,
        FastLevenbergMarquardt as FastLevenbergMarquardt,
        FitEnded as FitEnded,
        FitResult as FitResult,
        FitStarted as FitStarted,
        ModelScore as ModelScore,
        PredictionBand as PredictionBand,
        ProgressPrinter as ProgressPrinter,
        Selection as Selection,
        StepPolicy as StepPolicy,
        StepsRefined as StepsRefined,
        StopReason as StopReason,
        SystemRecord as SystemRecord,
        compare_models as compare_models,
        design_experiments as design_experiments,
        fit as fit,
        fit_each as fit_each,
        fit_report as fit_report,
        fit_system as fit_system,
        planned_test as planned_test,
        predict as predict,
        predict_all as predict_all,
        prediction_band as prediction_band,
        prediction_band_from_covariance as prediction_band_from_covariance,
        record_nrmse as record_nrmse,
        save_fit as save_fit,
        select_model as select_model,
        sine_grid as sine_grid,
    )
    from ._integrate import (
        AbstractIntegrator as AbstractIntegrator,
        Adaptive as Adaptive,
        FixedStep as FixedStep,
        Stiff as Stiff,
    )
    from ._magnetic import (
        BinghamDisc as BinghamDisc,
        HodgdonMaterial as HodgdonMaterial,
        MagneticStage as MagneticStage,
        aisi_12l14 as aisi_12l14,
        mr_brake_actuator as mr_brake_actuator,
        mrb_107_3 as mrb_107_3,
    )
    from ._misc import Check as Check
    from ._opensees import (
        from_opensees as from_opensees,
        to_opensees as to_opensees,
    )
    from ._parameter import (
        AbstractParameter as AbstractParameter,
        Bounded as Bounded,
        Fixed as Fixed,
        Positive as Positive,
        fit_only as fit_only,
    )
    from ._presets import (
        PRESETS as PRESETS,
        passenger_car_mr_damper as passenger_car_mr_damper,
        review_quarter_car_damper as review_quarter_car_damper,
        sas_brake_bingham as sas_brake_bingham,
        sas_brake_bouc_wen as sas_brake_bouc_wen,
        sas_brake_dahl as sas_brake_dahl,
        spencer_1997 as spencer_1997,
        utfsm_spencer as utfsm_spencer,
    )
    from ._ramp import Ramp as Ramp
    from ._road import (
        Cam as Cam,
        HaversineBump as HaversineBump,
        Pothole as Pothole,
        RandomRoad as RandomRoad,
        SmoothStep as SmoothStep,
        iso8608_psd as iso8608_psd,
        iso8608_road as iso8608_road,
        road_psd as road_psd,
    )
    from ._serialize import (
        load_fitted_range as load_fitted_range,
        load_model as load_model,
        model_from_dict as model_from_dict,
        model_to_dict as model_to_dict,
        save_model as save_model,
    )
    from ._signal import (
        AbstractSignal as AbstractSignal,
        Chirp as Chirp,
        Constant as Constant,
        Multisine as Multisine,
        Sampled as Sampled,
        Sine as Sine,
        Steps as Steps,
        Triangle as Triangle,
    )
    from ._simulate import simulate as simulate, sweep as sweep
    from ._solution import RESULTS as RESULTS, Solution as Solution
    from ._systems import (
        AbstractSystem as AbstractSystem,
        QuarterCar as QuarterCar,
        SASRig as SASRig,
        SingleDegreeOfFreedom as SingleDegreeOfFreedom,
        inverse_dynamics as inverse_dynamics,
        passenger_car as passenger_car,
        sas_rig as sas_rig,
        sas_rig_brake as sas_rig_brake,
        spencer_quarter_car as spencer_quarter_car,
    )
    from ._systems.oscillator import (
        band_limited_input as band_limited_input,
        hysteretic_benchmark_oscillator as hysteretic_benchmark_oscillator,
    )
    from ._tune import (
        TuneResult as TuneResult,
        cma_es as cma_es,
        evaluate as evaluate,
        random_search as random_search,
        tune as tune,
    )


# Submodules with their own vocabulary (files, figures, model templates, scores,
# metrics, linear control, devices, constants), imported on use as well.
_SUBPACKAGES = (
    "constants",
    "data",
    "devices",
    "linear",
    "metrics",
    "plot",
    "scores",
    "templates",
)
_exports: dict[str, tuple[str, str]] | None = None

# Names that left the top level in this release (CHANGELOG.md), kept one release as
# deprecated aliases: name -> the submodule that holds it now.
_MOVED = {
    "configure_cpu": "devices",
    "gather": "devices",
    "holdout_split": "scores",
    "moving_average": "scores",
    "nrmse": "scores",
    "score_table": "scores",
    "MODEL_TEMPLATES": "templates",
    "DataScales": "templates",
    "data_scales": "templates",
    "AISI_12L14_MAJOR_LOOP": "constants",
    "MEASUREMENT_NAMES": "constants",
    "UTFSM_SPENCER_PUBLISHED": "constants",
    "comfort": "metrics",
    "crest_factor": "metrics",
    "decay_settling_time": "metrics",
    "dissipated_energy": "metrics",
    "dissipated_work": "metrics",
    "energy_per_cycle": "metrics",
    "mean_current": "metrics",
    "peak": "metrics",
    "rms": "metrics",
    "rms_current": "metrics",
    "settling_time": "metrics",
    "vdv": "metrics",
    "wk_response": "metrics",
    "wk_rms": "metrics",
    "wk_state_space": "metrics",
    "wk_weighted": "metrics",
    "lqr": "linear",
    "quarter_car_state_space": "linear",
    "solve_lyapunov": "linear",
    "solve_riccati": "linear",
}


def _public() -> dict[str, tuple[str, str]]:
    """Public name -> (module, name in it), from the imports under `TYPE_CHECKING`."""
    global _exports
    if _exports is None:
        source = __spec__.loader.get_source(__name__)
        found = {}
        for node in ast.parse(source).body:
            if not (
                isinstance(node, ast.If) and ast.unparse(node.test) == "TYPE_CHECKING"
            ):
                continue
            for statement in node.body:
                if not isinstance(statement, ast.ImportFrom):
                    continue  # e.g. `import x` for annotations: not a public name
                module = "." * statement.level + (statement.module or "")
                for alias in statement.names:
                    found[alias.asname or alias.name] = (module, alias.name)
        _exports = found
    return _exports


def __getattr__(name: str) -> object:
    if name in _SUBPACKAGES:
        return importlib.import_module(f".{name}", __name__)
    if name == "__all__":
        return sorted(_public())
    if name in _MOVED:
        # Not stored in this module's globals: every use warns.
        where = f"{__name__}.{_MOVED[name]}"
        warnings.warn(
            f"`{__name__}.{name}` is deprecated and will be removed in the next "
            f"release: use `{where}.{name}` (import {where}).",
            DeprecationWarning,
            stacklevel=2,
        )
        return getattr(importlib.import_module(where), name)
    if name not in _public():
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    # Every public name at once: `vars(jaxmr)` then holds them all, as it did when
    # this file imported them eagerly.
    for public, (module, attribute) in _public().items():
        globals()[public] = getattr(
            importlib.import_module(module, __name__), attribute
        )
    return globals()[name]


def __dir__() -> list[str]:
    # The public API, the subpackages and the module's dunders; not the helpers
    # this file imports for itself (`ast`, `importlib`, ...).
    dunders = {n for n in globals() if n.startswith("__")}
    return sorted(dunders | set(_public()) | set(_SUBPACKAGES))
