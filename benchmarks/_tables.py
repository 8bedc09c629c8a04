"""The tables of headline figures in benchmarks/README.md, written from the result files.

    python benchmarks/_tables.py            # rewrite the README's generated blocks
    python benchmarks/_tables.py --check    # exit 1 where the README differs from them

Each benchmark's section of the README holds a block between `<!-- figures:NAME -->`
and `<!-- /figures:NAME -->`, rendered from `benchmarks/results/NAME.json` by the
`Table` named NAME below: its headline figures, the goal where an issue set one and
whether it is met, and the machine that measured them. A figure the file does not hold
(a benchmark not re-run since it gained the figure) reads "not measured". So a number
in those blocks is never typed: change the spec here, or re-run the benchmark
(`benchmarks/run_all.py`). Needs only the standard library.
"""

from __future__ import annotations

import argparse
import difflib
import json
import math
import re
import sys
from dataclasses import dataclass
from pathlib import Path

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"
README = HERE / "README.md"
NOT_MEASURED = "not measured"


@dataclass(frozen=True)
class Goal:
    """What a figure must show: within [low, high] (strict: the open interval), or
    True (`true`); `issue` is the issue that set it."""

    low: float | None = None
    high: float | None = None
    strict: bool = False
    true: bool = False
    issue: int | None = None

    def met(self, value) -> bool | None:
        """Whether `value` meets the goal; None where it cannot tell (a text). A
        spread over seeds is judged by its mean; a list by every entry."""
        if isinstance(value, dict) and "mean" in value:
            value = value["mean"]
        if isinstance(value, list):
            each = [self.met(v) for v in value]
            return None if None in each or not each else all(each)
        if self.true:
            return value is True if isinstance(value, bool) else None
        if isinstance(value, bool) or not isinstance(value, int | float):
            return None
        if math.isnan(value):
            return False
        if self.low is not None and not (
            value > self.low if self.strict else value >= self.low
        ):
            return False
        return self.high is None or (
            value < self.high if self.strict else value <= self.high
        )

    def text(self) -> str:
        if self.true:
            goal = "yes"
        elif self.low is not None and self.high is not None:
            goal = f"{self.low:g}–{self.high:g}"
        elif self.low is not None:
            goal = f"{'>' if self.strict else '≥'} {self.low:g}"
        else:
            goal = f"{'<' if self.strict else '≤'} {self.high:g}"
        return goal + (f" (issue {self.issue})" if self.issue else "")


def at_least(low: float, issue: int) -> Goal:
    return Goal(low=low, issue=issue)


def at_most(high: float, issue: int) -> Goal:
    return Goal(high=high, issue=issue)


def below(high: float, issue: int) -> Goal:
    return Goal(high=high, strict=True, issue=issue)


def between(low: float, high: float, issue: int) -> Goal:
    return Goal(low=low, high=high, issue=issue)


def is_true(issue: int) -> Goal:
    return Goal(true=True, issue=issue)


@dataclass(frozen=True)
class Row:
    """One figure: `key` is its path in the JSON (`/` between levels, a number
    indexes a list); `fmt` a format string for its numbers (default: `_number`)."""

    key: str
    label: str = ""
    goal: Goal | None = None
    fmt: str | None = None


@dataclass(frozen=True)
class Table:
    """The block `name` (results/`name`.json), at the top of `script`'s section."""

    name: str
    script: str
    rows: tuple[Row, ...]


# The criterion comparison's two ratios, in both of its runs' tables.
_I_OVER_D = (
    Row(
        "i_over_d_geomean",
        "I-optimal plan's held-out NRMSE over D-optimal's, geometric mean over "
        "5 simulated dampers (mean over 10 noise seeds)",
    ),
    Row("i_over_d_geomean_seed_medians", "the same with the median over the seeds"),
)

# --- the headline figures of each benchmark ------------------------------------------

TABLES = (
    Table(
        "simulate_sweep",
        "simulate_sweep.py",
        (
            Row(
                "speedup_vs_scipy_vectorised",
                "against the vectorised SciPy/NumPy baseline, compilation excluded",
                at_least(10, 28),
            ),
            Row("scipy_vectorised_baseline", "which vectorised baseline was faster"),
            Row(
                "speedup_vs_numba",
                "against numba's parallel RK4 loop, compilation excluded",
                at_least(1, 28),
            ),
            Row(
                "speedup_vs_scipy_vectorised_with_compile",
                "the same, compilation counted",
            ),
            Row("speedup_vs_numba_with_compile", "the same, compilation counted"),
            Row("jaxmr_devices", "XLA CPU devices jaxmr ran on (`configure_cpu`)"),
            Row(
                "speedup_vs_numba_one_device",
                "jaxmr on one device against numba on one thread",
            ),
            Row(
                "speedup_vs_numba_cpu_time",
                "against numba in process CPU time (both on every core)",
            ),
            Row(
                "speedup_vs_scipy_vectorised_no_sharing",
                "one solve per run on both sides",
            ),
            Row("speedup_vs_numba_no_sharing", "one solve per run on both sides"),
            Row(
                "throughput_sim_s_per_s",
                "jaxmr, simulated s per wall s (compilation excluded)",
            ),
            Row(
                "speedup_vs_scipy_loop",
                "against the per-run `solve_ivp` loop (the old baseline)",
                at_least(250, 12),
            ),
            Row(
                "time_ratio_vs_scan_kernel",
                "time over a hand-written `lax.scan` kernel's",
                at_most(2, 12),
            ),
            Row("all_within_target", "every method within 1e-3 of peak", is_true(28)),
        ),
    ),
    Table(
        "identify_speed",
        "identify_speed.py",
        (
            Row(
                "speedup_joint_vs_scipy_fd",
                "UTFSM 30-run joint fit against scipy `least_squares` with finite "
                "differences, compilation included",
                at_least(2, 28),
            ),
            Row(
                "speedup_joint_vs_scipy_fd_cpu_time",
                "the same in CPU time (every core's), compilation included",
            ),
            Row(
                "speedup_vs_scipy_fd",
                "Bouc–Wen benchmark, the same comparison, compilation included",
                at_least(1, 28),
            ),
            Row(
                "speedup_vs_scipy_fd_excluding_compile",
                "the same, compilation excluded",
            ),
            Row(
                "speedup_vs_scipy_fd_cpu_time",
                "the same in CPU time (every core's), compilation included",
            ),
            Row(
                "speedup_joint_vs_scipy_exact_jacobian",
                "UTFSM joint fit against scipy with jaxmr's exact Jacobian",
            ),
            Row("first_fit_seconds", "a first `jaxmr fit` (cold cache) [s]"),
            Row(
                "second_fit_seconds",
                "a second `jaxmr fit` of the same files [s] (median of its runs)",
            ),
            Row(
                "second_fit_compile_seconds",
                "tracing and compilation of a second `jaxmr fit` of the same files [s] "
                "(median of its runs)",
                at_most(1, 28),
            ),
            Row(
                "simulated_steps_per_data_step",
                "RK4 steps simulated per data step (packed)",
                at_most(1.2, 9),
            ),
            Row(
                "jacobian_cost_in_residuals",
                "Jacobian's cost in residuals (14 parameters)",
                at_most(15, 9),
            ),
            Row(
                "seconds_joint_fit",
                "joint fit, compilation included [s]",
                at_most(30, 9),
            ),
            Row("joint_fit_median_nrmse", "joint fit, median NRMSE on the 30"),
            Row("seconds_auto", "`jaxmr fit`, default auto [s]", at_most(180, 9)),
            Row("auto_choice", "auto's choice"),
            Row(
                "auto_median_nrmse_all_30",
                "its median NRMSE on all 30",
                at_most(0.075, 9),
            ),
            Row("nees_held_out_nrmse", "NEES, NRMSE on the held-out last third"),
            Row(
                "nees_improvement_over_spencer_1997",
                "NEES, better than Spencer 1997 by",
                at_least(0.30, 9),
            ),
        ),
    ),
    Table(
        "cpu_flags",
        "cpu_flags.py",
        (
            Row("utfsm_residual_speedup", "UTFSM residual, run speedup"),
            Row("utfsm_jacobian_speedup", "UTFSM residual with its Jacobian"),
            Row("boucwen_residual_speedup", "Bouc–Wen oscillator residual"),
            Row("boucwen_jacobian_speedup", "Bouc–Wen oscillator Jacobian"),
            Row("sweep_speedup", "`sweep`, 256 runs"),
            Row(
                "utfsm_residual_compile_speedup_older_emitters",
                "older fusion emitters: UTFSM residual, compile speedup",
            ),
            Row(
                "utfsm_jacobian_compile_speedup_older_emitters",
                "older emitters: UTFSM Jacobian, compile speedup",
            ),
            Row(
                "boucwen_residual_compile_speedup_older_emitters",
                "older emitters: oscillator residual, compile speedup",
            ),
            Row(
                "boucwen_jacobian_compile_speedup_older_emitters",
                "older emitters: oscillator Jacobian, compile speedup",
            ),
            Row(
                "sweep_compile_speedup_older_emitters",
                "older emitters: `sweep`, compile speedup",
            ),
            Row(
                "utfsm_jacobian_run_ratio_older_emitters",
                "older emitters: UTFSM Jacobian, run time ratio (1: same)",
            ),
            Row(
                "boucwen_jacobian_run_ratio_older_emitters",
                "older emitters: oscillator Jacobian, run time ratio",
            ),
            Row(
                "sweep_run_ratio_older_emitters",
                "older emitters: `sweep`, run time ratio",
            ),
        ),
    ),
    Table(
        "fit_vs_scipy",
        "fit_vs_scipy.py",
        (
            Row(
                "speedup_vs_scipy_fixedstep",
                "scipy FD's time over `jaxmr.fit`'s (compilation excluded)",
            ),
            Row("jaxmr/run_s", "`jaxmr.fit` after compiling [s]"),
            Row("jaxmr/first_call_s", "`jaxmr.fit`, first call [s]"),
            Row("scipy_fd_fixedstep/run_s", "scipy FD, fixed-step residual [s]"),
            Row(
                "scipy_fd_fixedstep/residual_evaluations",
                "its residual evaluations",
            ),
        ),
    ),
    *(
        Table(
            f"boucwen_{kind}",
            "boucwen_benchmark.py",
            (
                Row(
                    "e_rms_vs_true_model_m/fitted",
                    f"{label}: e_RMS of the fitted model against the true model [m]",
                ),
                Row(
                    "e_rms_vs_true_model_m/linear",
                    "e_RMS of the linear model [m]",
                ),
                Row("e_rms_vs_true_model_m/scipy", "e_RMS of scipy's fit [m]"),
                Row(
                    "speedup_vs_scipy_fd",
                    "against scipy `least_squares` with finite differences, "
                    "compilation included",
                    at_least(1, 28),
                ),
                Row(
                    "speedup_vs_scipy_fd_excluding_compile",
                    "the same, compilation excluded",
                ),
                Row(
                    "speedup_vs_scipy_fd_cpu_time",
                    "the same in CPU time (every core's), compilation included",
                ),
                Row(
                    "fit/total_seconds",
                    "`fit_system`, compilation included [s]",
                ),
            ),
        )
        for kind, label in (("multisine", "multisine"), ("sinesweep", "sine sweep"))
    ),
    Table(
        "quarter_car_control",
        "quarter_car_control.py",
        (
            Row(
                "comfort_fresh_mean",
                "comfort gain over the best constant, fresh road sets, mean",
                at_least(0.16, 28),
            ),
            Row(
                "comfort_fresh_per_seed_set_mean",
                "its spread over tuning seeds (mean ± sd, min–max)",
            ),
            Row(
                "comfort_fresh_min", "the worst fresh set and seed", at_least(0.14, 28)
            ),
            Row(
                "constrained_fresh",
                "constrained law, fresh road sets, margin frozen before scoring",
                at_least(0.12, 28),
            ),
            Row(
                "constrained_fresh_feasible_per_set",
                "the constrained law within the tyre limit on each fresh set",
                is_true(28),
            ),
            Row(
                "cmaes_wall_ratio",
                "CMA-ES (best of its grid) wall clock to the gradient's loss, over "
                "the gradient's",
                at_least(3, 28),
            ),
            Row("cmaes_wall_ratio_spread", "over seeds (mean ± sd, min–max)"),
            Row(
                "cmaes_forward_ratio",
                "the same in forward-simulation equivalents",
                at_least(3, 28),
            ),
            Row("cmaes_forward_ratio_spread", "over seeds (mean ± sd, min–max)"),
            Row(
                "cmaes_reached_gradient_loss",
                "CMA-ES reached the gradient's loss (per seed; where not, the "
                "ratios are lower bounds)",
            ),
            Row(
                "cmaes_gap_at_budget",
                "where not: its loss over the gradient's − 1 at the end of its budget",
            ),
            Row(
                "robust_worst_fresh_gain",
                "robust over nominal law, worst fresh damper sample",
                below(1, 28),
            ),
            Row("robust_worst_fresh_gain_spread", "over seeds (mean ± sd, min–max)"),
            Row(
                "skyhook_from_far_start",
                "skyhook tuned from 10x too soft, over the grid's best − 1",
                at_most(0.01, 10),
            ),
            Row(
                "time_ratio_vs_scan_kernel",
                "closed loop, time over a `lax.scan` kernel's",
                at_most(1.5, 10),
            ),
            Row(
                "gradient_time_ratio_vs_scan_kernel",
                "its gradient, the same",
                at_most(2, 10),
            ),
            Row("bound_reduction_comfort", "optimal schedule over the best constant"),
        ),
    ),
    Table(
        "sas_rig",
        "sas_rig.py",
        (
            Row(
                "controller_settling_ratio",
                "best law's settling time over the fastest constant current's",
                at_most(1.1, 5),
            ),
            Row(
                "controller_current_ratio",
                "its mean current over that constant's",
                at_most(0.5, 5),
            ),
        ),
    ),
    Table(
        "closed_loop",
        "closed_loop_kernel.py",
        (
            Row("closed_loop_sim_s_per_s", "jaxmr forward, simulated s per wall s"),
            Row("gradient_sim_s_per_s", "jaxmr gradient, simulated s per wall s"),
            Row(
                "time_ratio_vs_scan_kernel",
                "forward, time over the kernel's",
                at_most(1.5, 10),
            ),
            Row(
                "gradient_time_ratio_vs_scan_kernel",
                "gradient, time over the kernel's",
                at_most(2, 10),
            ),
            Row(
                "specialised_time_ratio_vs_scan_kernel",
                "forward, over the specialised kernel's",
            ),
        ),
    ),
    Table(
        "opensees_check",
        "opensees_check.py",
        tuple(
            row
            for i, material in enumerate(
                ("BoucWen", "BoucWen with degradation", "BWBN with pinching")
            )
            for row in (
                Row(
                    f"cases/{i}/richardson_error_of_peak",
                    f"{material}: error of peak after Richardson extrapolation",
                ),
                Row(f"cases/{i}/mapping_right", "first order, agrees in the limit"),
            )
        ),
    ),
    Table(
        "experiment_design",
        "experiment_design.py",
        (
            Row(
                "designed_over_all",
                "held-out NRMSE of the default criterion's plan over all tests' fit",
                at_most(1.10, 28),
            ),
            Row("criterion", "the default criterion"),
            Row("designed_nrmse", "designed plan, held-out NRMSE"),
            Row("all_nrmse", "fit on all tests"),
            Row("random_median_nrmse", "random plans, median held-out NRMSE"),
            Row(
                "brake_max_factor",
                "synthetic brake: realised over predicted standard errors, worst",
                at_most(1.5, 13),
            ),
        ),
    ),
    Table(
        "design_criterion_choice",
        "design_criterion_choice.py",
        (
            *_I_OVER_D,
            Row("i_over_d_min", "the lowest damper's ratio"),
            Row("i_over_d_max", "the highest damper's ratio"),
            Row(
                "d_over_random_geomean",
                "D-optimal plan over the median random plan, geometric mean",
            ),
            Row(
                "rule_switches_to_i",
                "the rule fixed before the run (I/D below 0.95 by the means and below 1 by the medians) says switch",
            ),
        ),
    ),
    Table(
        "design_criterion_choice_starts4",
        "design_criterion_choice.py",
        (
            Row("starts", "starts per fit (the rule's run: 1)"),
            *_I_OVER_D,
            Row(
                "presets/spencer_1997/D",
                "Spencer 1997: D plan's held-out NRMSE, mean over the seeds",
            ),
            Row("presets/spencer_1997/I", "Spencer 1997: I plan's, the same"),
            Row(
                "presets/review_quarter_car_damper/D",
                "the review's damper: D plan's held-out NRMSE, mean over the seeds",
            ),
            Row(
                "presets/review_quarter_car_damper/I",
                "the review's damper: I plan's, the same",
            ),
            Row(
                "d_over_random_geomean",
                "D-optimal plan over the median random plan, geometric mean",
            ),
        ),
    ),
    Table(
        "gpu_throughput",
        "gpu_throughput.py",
        (
            Row(
                "gpu_speedup_sweep",
                "`sweep`, 65 536 damper runs: accelerator over the same machine's CPU, "
                "compilation excluded",
            ),
            Row("gpu_speedup_sweep_with_compile", "the same, compilation included"),
            Row("gpu_sweep_sim_s_per_s", "accelerator: simulated s per wall s"),
            Row(
                "cpu_sweep_sim_s_per_s", "CPU (`configure_cpu`): simulated s per wall s"
            ),
            Row(
                "gpu_speedup_closed_loop",
                "`evaluate`, skyhook on 8 192 roads: accelerator over CPU, compilation "
                "excluded",
            ),
            Row(
                "gpu_speedup_closed_loop_with_compile",
                "the same, compilation included",
            ),
            Row("gpu_closed_loop_sim_s_per_s", "accelerator: simulated s per wall s"),
            Row("cpu_closed_loop_sim_s_per_s", "CPU: simulated s per wall s"),
            *(
                Row(
                    f"{side}/{case}/{n}/{figure}",
                    f"{'accelerator' if side == 'accelerator' else 'CPU'}, "
                    f"{label.format(n=n)}: {what}",
                )
                for case, label, sizes in (
                    ("sweep", "sweep of {n} runs", (1024, 8192)),
                    ("closed_loop", "closed loop on {n} roads", (64, 1024)),
                )
                for n in sizes
                for side in ("accelerator", "cpu")
                for figure, what in (("sim_s_per_s", "simulated s per wall s"),)
            ),
            *(
                Row(
                    f"{side}/{case}/{n}/compile_s",
                    f"{'accelerator' if side == 'accelerator' else 'CPU'}, {label}: "
                    "compilation [s]",
                )
                for case, label, n in (
                    ("sweep", "largest sweep", 65536),
                    ("closed_loop", "largest closed loop", 8192),
                )
                for side in ("accelerator", "cpu")
            ),
        ),
    ),
    Table(
        "fit_each_scaling",
        "fit_each_scaling.py",
        (
            Row(
                "seconds_256_fits",
                "one process, compilation included [s]",
                at_most(120, 12),
            ),
            Row(
                "two_process_over_one",
                "2 processes' time over one's",
                at_most(1.15, 12),
            ),
            Row("equal_results", "equal results bit for bit", is_true(12)),
            Row(
                "fraction_recovered",
                "values within 3 standard errors of the truth",
                at_least(0.95, 12),
            ),
            Row("median_steps", "median LM steps"),
        ),
    ),
    Table(
        "calibration",
        "calibration.py",
        (
            Row(
                "min_coverage",
                "coverage of nominal 95 % intervals, worst case",
                between(0.90, 0.98, 25),
            ),
            Row("max_coverage", "the same, best case", between(0.90, 0.98, 25)),
            Row(
                "band_coverage",
                "95 % prediction band on a held-out test, worst case",
                between(0.90, 0.98, 25),
            ),
        ),
    ),
    Table(
        "generalisation",
        "generalisation.py",
        (
            Row(
                "max_regret",
                "auto's held-out NRMSE over the best in hindsight − 1, worst dataset",
                at_most(0.10, 25),
            ),
            Row("median_regret", "the same, median", at_most(0.03, 25)),
            Row(
                "fresh_max_regret",
                "the same on the simulated draw made after the defaults were "
                "frozen only, worst",
                at_most(0.10, 25),
            ),
            Row("fresh_median_regret", "the same, median", at_most(0.03, 25)),
            Row("seconds", "whole run [s]"),
        ),
    ),
    Table(
        "saturation_choice",
        "saturation_choice.py",
        (
            Row(
                "num_datasets",
                "choice datasets (utfsm, nees, draws 1 and 2 of 7 presets)",
            ),
            Row("today_max_regret", "former defaults: worst regret"),
            Row("saturating_max_regret", "with the saturating variants: worst regret"),
            Row("today_median_regret", "former defaults: median regret"),
            Row(
                "saturating_median_regret",
                "with the saturating variants: median regret",
            ),
            Row(
                "time_factor_equal_load",
                "auto's median wall time with them over without (runs under equal load)",
                at_most(2.0, 25),
            ),
            Row("adopt_saturating", "the rule adopts them", is_true(25)),
        ),
    ),
    Table(
        "screening_folds_choice",
        "screening_folds_choice.py",
        (
            Row(
                "num_datasets",
                "choice datasets (utfsm, nees, draws 2 and 4 of 7 presets)",
            ),
            Row("first_max_regret", "screened on the first fold: worst regret"),
            Row("every_max_regret", "screened on every fold: worst regret"),
            Row("first_median_regret", "screened on the first fold: median regret"),
            Row("every_median_regret", "screened on every fold: median regret"),
            Row(
                "time_factor",
                "auto's median wall time, every fold over the first",
                at_most(2.0, 25),
            ),
            Row("adopt_every", "the rule adopts screening on every fold"),
        ),
    ),
    Table(
        "trust_region_choice",
        "trust_region_choice.py",
        (
            Row("chosen_initial_radius", "the first trust region the rule chose"),
            *(
                row
                for r in ("1.0", "10.0", "100.0")
                for row in (
                    Row(
                        f"summary/{r}/worst_loss_over_best",
                        f"radius {r[:-2]}: worst final loss over the best radius's, "
                        "over the 14 fits",
                    ),
                    Row(
                        f"summary/{r}/geomean_time_ratio",
                        f"radius {r[:-2]}: time to the target over radius 1's, "
                        "geometric mean (compilation excluded)",
                    ),
                    Row(f"summary/{r}/steps", f"radius {r[:-2]}: steps, all fits"),
                )
            ),
        ),
    ),
    Table(
        "screening_choice",
        "screening_choice.py",
        (
            Row(
                "lodo_max_regret",
                "leave-one-dataset-out regret of the screening and statistic "
                "chosen on the other datasets, worst dataset",
                at_most(0.10, 25),
            ),
            Row("lodo_median_regret", "the same, median", at_most(0.03, 25)),
            Row(
                "lodo_damper_max_regret",
                "the same leaving out both draws of a simulated damper together, "
                "worst dataset",
                at_most(0.10, 25),
            ),
        ),
    ),
    Table(
        "starts_choice",
        "starts_choice.py",
        (
            Row(
                "starts4_geomean_ratio",
                "4 starts per fit: auto's held-out median NRMSE over one start's, "
                "geometric mean over the choice datasets (rule: ≤ 0.95)",
            ),
            Row(
                "starts4_max_ratio",
                "the same, worst dataset (rule: ≤ 1.10)",
            ),
            Row(
                "starts4_time_factor",
                "auto's wall time, 4 starts over one (rule: ≤ 2)",
            ),
            Row("chosen_starts", "the starts per fit the rule chooses"),
        ),
    ),
    Table(
        "fold_choice",
        "fold_choice.py",
        (
            Row(
                "geomean_ratio",
                "folds holding out different records: auto's held-out median "
                "NRMSE over the baseline folds', geometric mean over the datasets "
                "whose folds change (rule: ≤ 1.00)",
            ),
            Row("max_ratio", "the same, worst dataset (rule: ≤ 1.10)"),
            Row("time_factor", "auto's wall time, new folds over the baseline's"),
            Row("keep_new_folds", "whether the rule keeps the new folds"),
        ),
    ),
    Table(
        "held_out_currents",
        "held_out_currents.py",
        (
            Row("choice", "`jaxmr fit`'s choice on the 0, 0.5, 1 A files"),
            Row(
                "all_30_median_nrmse",
                "its median NRMSE on all 30 files",
                at_most(0.07, 25),
            ),
            Row("held_out_median_nrmse", "on the 12 held-out (0.25, 0.75 A) files"),
            Row(
                "published_held_out_median_nrmse",
                "the published model on the same 12",
            ),
            Row("held_out_better_than_published", "held-out files where it is better"),
            Row(
                "goals/held_out beats published",
                "held-out median below the published model's",
                is_true(25),
            ),
        ),
    ),
    Table(
        "realistic_control",
        "realistic_control.py",
        (
            Row("comfort_perfect", "(a) today's law, perfect information"),
            Row(
                "comfort_realistic_joint",
                "(b) law and estimator tuned together, realistic sensors",
                at_least(0.14, 29),
            ),
            Row(
                "comfort_realistic_deployed",
                "(c) tuned with perfect information, run with realistic sensors",
            ),
            Row(
                "joint_minus_deployed_paired_mean",
                "(b) − (c), paired: 24 more fresh roads × 3 noise draws",
            ),
            Row(
                "joint_minus_deployed_paired_se",
                "its standard error (over the roads)",
            ),
            Row(
                "joint_minus_deployed_paired_z",
                "mean / standard error (session 13's check, too few roads to tell)",
            ),
            Row("joint_better_share_of_roads", "share of those roads where (b) wins"),
            Row(
                "joint_minus_deployed_large_mean",
                "(b) − (c), paired: 240 more fresh roads × 3 noise draws",
            ),
            Row("joint_minus_deployed_large_se", "its standard error (over the roads)"),
            Row(
                "joint_minus_deployed_large_z",
                "mean / standard error: (b) better than (c) beyond the scatter",
                at_least(2, 29),
            ),
            Row(
                "joint_better_share_of_roads_large",
                "share of those roads where (b) wins",
            ),
        ),
    ),
    Table(
        "export_c",
        "export_c.py",
        (
            Row(
                "c_step_microseconds",
                "exported C step, 84-weight law with its observer [µs]",
                at_most(5, 29),
            ),
        ),
    ),
)


# --- rendering -----------------------------------------------------------------------


def _number(value: float) -> str:
    """A figure as the README writes it: 3 significant digits, whole numbers from
    100, thousands split by a space."""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return f"{value:,}".replace(",", " ")
    if math.isnan(value) or math.isinf(value):
        return str(value)
    size = abs(value)
    if size >= 1000:
        return f"{value:,.0f}".replace(",", " ")
    if size >= 100:
        return f"{value:.0f}"
    if size == 0 or size >= 1e-3:
        return f"{value:#.3g}".rstrip(".")
    return re.sub(r"e([+-])0*(\d)", r"e\1\2", f"{value:.2g}").replace("e+", "e")


def _value(value, fmt: str | None) -> str:
    if isinstance(value, dict) and "mean" in value:  # a spread over seeds
        part = lambda v: _value(v, fmt)
        text = part(value["mean"])
        if "std" in value:
            text += f" ± {part(value['std'])}"
        if "min" in value and "max" in value:
            text += f" ({part(value['min'])}–{part(value['max'])})"
        return text
    if isinstance(value, list):
        return ", ".join("–" if v is None else _value(v, fmt) for v in value)
    if isinstance(value, str):
        return value
    if isinstance(value, bool) or fmt is None or not isinstance(value, int | float):
        return _number(value) if isinstance(value, int | float) else str(value)
    return fmt.format(value)


_MISSING = object()


def lookup(figures, key: str):
    """The entry of `figures` at `key` (`a/b/0`), or `_MISSING`."""
    value = figures
    for part in key.split("/"):
        if isinstance(value, dict) and part in value:
            value = value[part]
        elif isinstance(value, list) and part.isdigit() and int(part) < len(value):
            value = value[int(part)]
        else:
            return _MISSING
    return value


def _machine_line(figures: dict) -> str:
    """Where and when the figures were measured, from their `machine` block."""
    machine = figures.get("machine")
    if not isinstance(machine, dict) or "cpu" not in machine:
        date = figures.get("date") or (
            machine.get("date") if isinstance(machine, dict) else None
        )
        note = machine if isinstance(machine, str) else None
        parts = [f"measured {str(date)[:10]}" if date else None, note]
        said = ", ".join(p for p in parts if p)
        return (
            f"Machine not recorded ({said}): measured before `run_all.py`."
            if said
            else "Machine not recorded: measured before `run_all.py`."
        )
    load = " → ".join(
        _number(float(machine[k][0]))
        for k in ("load_average_start", "load_average_end")
        if machine.get(k)
    )
    versions = machine.get("versions") or {}
    software = ", ".join(
        f"{name} {versions[name]}"
        for name in ("jax", "jaxlib", "numpy", "scipy")
        if versions.get(name)
    )
    git = machine.get("git") or {}
    commit = git.get("commit", "")[:10] or "unknown commit"
    if git.get("changed"):
        commit += f" with {len(git['changed'])} changed files"
    return (
        f"Measured {str(machine.get('date', ''))[:10]} on {machine.get('cpu')} "
        f"({machine.get('cores')} cores), load average (1 min) {load}; {software}; "
        f"commit {commit}."
    )


def render(table: Table, figures: dict | None, source: str) -> str:
    """The block's body: the table of `figures` (None: no result file)."""
    lines = [
        f"<!-- written by benchmarks/_tables.py from {source}: do not edit here -->",
        "",
        "| figure | measured | goal | met |",
        "|---|---:|---|---|",
    ]
    for row in table.rows:
        value = _MISSING if figures is None else lookup(figures, row.key)
        name = f"`{row.key}`" + (f": {row.label}" if row.label else "")
        goal = row.goal.text() if row.goal else ""
        if value is _MISSING or value is None:
            shown, met = NOT_MEASURED, "–" if row.goal else ""
        else:
            shown = _value(value, row.fmt)
            verdict = row.goal.met(value) if row.goal else None
            met = {True: "met", False: "**not met**", None: ""}[verdict]
            if row.goal and verdict is None:
                met = "?"
        lines.append(f"| {name} | {shown} | {goal} | {met} |")
    lines.append("")
    if figures is None:
        lines.append(
            f"Not measured yet: no `{source}` "
            f"(`python benchmarks/run_all.py --only {table.name}`)."
        )
    else:
        if figures.get("quick"):
            lines.append("**A `--quick` smoke run, not a measurement.**")
        lines.append(_machine_line(figures))
    return "\n".join(lines)


def load(table: Table, results: Path) -> dict | None:
    path = results / f"{table.name}.json"
    return json.loads(path.read_text()) if path.exists() else None


def blocks(results: Path = RESULTS) -> dict[str, str]:
    """Every table's block body, from the JSON files in `results`."""
    return {
        t.name: render(t, load(t, results), f"results/{t.name}.json") for t in TABLES
    }


def _markers(name: str) -> tuple[str, str]:
    return f"<!-- figures:{name} -->", f"<!-- /figures:{name} -->"


def update(text: str, bodies: dict[str, str]) -> str:
    """`text` (the README) with each named block's body replaced. A block not yet in
    it goes at the top of its script's section (after the heading and the blocks
    already there)."""
    scripts = {t.name: t.script for t in TABLES}
    for name, body in bodies.items():
        begin, end = _markers(name)
        block = f"{begin}\n{body}\n{end}"
        pattern = re.compile(re.escape(begin) + r".*?" + re.escape(end), re.DOTALL)
        if found := pattern.search(text):
            text = text[: found.start()] + block + text[found.end() :]
            continue
        heading = re.search(
            rf"^## `{re.escape(scripts[name])}`.*\n", text, flags=re.MULTILINE
        )
        if heading is None:
            raise ValueError(f"README: no section `## `{scripts[name]}`` for {name}")
        at = heading.end()
        after = re.compile(
            r"\n*<!-- figures:[^>]*-->.*?<!-- /figures:[^>]*-->\n", re.DOTALL
        )
        while match := after.match(text, at):
            at = match.end()
        text = text[:at] + f"\n{block}\n" + text[at:]
    return text


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--check",
        action="store_true",
        help="exit 1 (with a diff) where the README differs from the result files",
    )
    parser.add_argument("--results", type=Path, default=RESULTS)
    parser.add_argument("--readme", type=Path, default=README)
    parser.add_argument(
        "--print", action="store_true", help="print the blocks, change nothing"
    )
    args = parser.parse_args(argv)
    bodies = blocks(args.results)
    if args.print:
        for name, body in bodies.items():
            print(f"## {name}\n\n{body}\n")
        return 0
    current = args.readme.read_text()
    try:
        wanted = update(current, bodies)
    except ValueError as error:
        print(error, file=sys.stderr)
        return 1
    if args.check:
        if wanted == current:
            print(f"{args.readme}: the tables agree with {args.results}")
            return 0
        sys.stdout.writelines(
            difflib.unified_diff(
                current.splitlines(keepends=True),
                wanted.splitlines(keepends=True),
                str(args.readme),
                "from the result files",
            )
        )
        print(
            f"{args.readme} differs from {args.results}: run "
            "`python benchmarks/_tables.py`",
            file=sys.stderr,
        )
        return 1
    if wanted != current:
        args.readme.write_text(wanted)
        print(f"{args.readme}: tables rewritten from {args.results}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
