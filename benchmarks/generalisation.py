"""Does `jaxmr fit`'s model selection generalise to a damper it was not tuned on?
(issue 25, item 1)

For every damper the project has (`_generalisation_data.py`: the UTFSM sine tests, the
NEES random record, simulated tests of each preset damper with white and AR(1) noise;
by default the simulated draw `FRESH_DRAW`, drawn after the selection defaults were
frozen, and the two real datasets, which the defaults were chosen on), split into training records and held-out records (held-out input levels and held-out
records), this measures:

- `auto`: `select_model` run the way `jaxmr fit --model auto` runs it with its defaults
  (the default candidates, their `_lag` variants when the input varies within a
  record, 2 finalists, at most 200 steps, each record's discard and smoothing) on the
  training records; its choice, the refitted model's median NRMSE on the held-out
  records, and its wall time (compilation included);
- `plain`: every candidate of the library's family list (Bingham, Dahl, LuGre,
  Bouc–Wen, Spencer, shear-thinning Spencer, the `_lag` variants where the input
  varies in time, and the `_saturating` variants with 3 or more input levels) fitted
  from its template on the training records with `jaxmr fit`'s defaults: loss,
  steps, verdict, time, median held-out NRMSE;
- `regret` = (auto's held-out NRMSE) / (the best plain candidate's) − 1, and over the
  datasets `max_regret` and `median_regret` (goal: ≤ 10 % and ≤ 3 %);
- `cv`: inside the training records only, two folds (`levels`: `holdout_split`, what
  `select_model` holds out today; `records`: every third record by name, a different
  amplitude/frequency or segment), each candidate screened as `compare_models` does
  (`SCREEN_STEPS` steps on the screening stretch) and then fully fitted from its
  screening fit; per-record held-out NRMSEs and times of both stages. From these,
  `analysis` chooses a candidate set, screening and fold scheme and a parsimony rule
  by leave-one-dataset-out (each rule chosen on the other datasets, scored on the
  left-out one), and reports the regret each dataset then gets.

    python benchmarks/generalisation.py --json benchmarks/results/generalisation.json

The headline figures (`results/generalisation.json`) come from one process per
dataset, each `--small --no-cv --max-steps 100 --datasets D --json /tmp/gen_D.json`,
merged with `--analyse /tmp/gen_*.json --json results/generalisation.json`;
`--separate` does exactly that (what `run_all.py` runs):

    python benchmarks/generalisation.py --small --no-cv --max-steps 100 --separate \
        --json benchmarks/results/generalisation.json

`--quick` is a smoke run (fewer records, two datasets unless `--datasets` names
others, fewer steps). The JSON is rewritten after every dataset, so a long run can be
read while it goes on; `--analyse FILE` re-runs only the analysis on a written JSON.
The seeds of the simulated noise are `_generalisation_data.DRAW_SEEDS`, one per
draw (`sim_<preset>` is draw 1, `sim_<preset>@2` draw 2, ...; `--datasets` names
them). `datasets_used_in_choice` lists the datasets seen before the defaults were
frozen (the real ones and every draw before `_generalisation_data.FRESH_DRAW`),
`fresh_datasets` the others, with their own `fresh_max_regret` and
`fresh_median_regret`.
`--plain-only` fits only the plain candidates (the yardstick `screening_choice.py`
reads). `--auto-candidates today|saturating` runs the selection with the candidates of
before session 29 or with the saturating variants (the options of
`saturation_choice_rule.md`, scored by `saturation_choice.py`). `--screen-folds
every|first` screens the selection's candidates on every fold or on the first
(the options of `screening_folds_rule.md`, scored by `screening_folds_choice.py`).

The headline of 2026-11-28 (session 30): the seven presets' draw 5 (`FRESH_DRAW`,
its seed drawn after `screening_folds_rule.md` kept the screening on the first
fold), each in a process of its own, two at a time, and `utfsm` and `nees` from the
choice runs of `saturation_choice.py` (the same code and defaults: the `saturating`
selection with the `today` run's plain fits), merged with `--analyse`.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _report import write_figures

import jaxmr
import jaxmr.devices

# As `jaxmr fit` does: every CPU core an XLA device (up to 8).
jaxmr.devices.configure_cpu()

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import _generalisation_data as gd  # noqa: E402
import numpy as np  # noqa: E402

# Every public name of jaxmr now (the first use resolves them all), from the modules
# as they are at start-up: a run takes an hour, and the files may change meanwhile.
from jaxmr import fit, record_nrmse  # noqa: E402
from jaxmr._identify.select import (  # noqa: E402
    AUTO_STARTS,
    MIN_FINALISTS,
    SCREEN_FOLDS,
    SCREEN_STEPS,
    _complexity as _select_complexity,
    holdout_split,
    screening_end,
    select_model,
)
from jaxmr._identify.templates import (  # noqa: E402
    DEFAULT_CANDIDATES as AUTO_CANDIDATES,
    MODEL_TEMPLATES,
    default_candidates,
    input_varies_in_time,
    saturating_candidates,
)

# `jaxmr fit`'s defaults (jaxmr/_cli.py: --max-steps, --finalists, --starts).
MAX_STEPS = 200
FINALISTS = MIN_FINALISTS  # the library's (and `jaxmr fit`'s) default
# The library's families, simplest first (the order of the parsimony rule); the
# `_lag` variants join where the input varies within a record.
FAMILIES = ("bingham", "dahl", "lugre", "bouc_wen", "spencer", "shear_thinning_spencer")
LAGGED = ("bouc_wen_lag", "spencer_lag", "shear_thinning_spencer_lag")
QUICK_DATASETS = ("sim_review_quarter_car_damper", "utfsm")


def family_list(experiments) -> list[str]:
    """The yardstick's candidates: every family, the `_lag` variants where the
    input varies, and the `_saturating` variants with 3 or more input levels."""
    names = list(FAMILIES)
    if input_varies_in_time(experiments):
        names += list(LAGGED)
    return names + saturating_candidates(experiments)


# The candidate sets `--auto-candidates` compares (saturation_choice_rule.md):
# `default`, the library's; `today`, the library's before session 29 (every family,
# the `_lag` variants where the input varies); `saturating`, those and the
# `_saturating` variants with 3 or more input levels.
AUTO_SETS = ("default", "today", "saturating")


def auto_candidates(experiments, which: str = "default") -> list[str]:
    """The candidates of the selection for these records: `jaxmr fit`'s defaults,
    or one of the sets of `AUTO_SETS`."""
    if which == "default":
        return default_candidates(experiments)
    names = list(FAMILIES)
    if input_varies_in_time(experiments):
        names += list(LAGGED)
    if which == "saturating":
        names += saturating_candidates(experiments)
    return names


def _scores(model, records, discard, smoothing) -> list[float]:
    values = record_nrmse(model, records, discard=discard, smoothing=smoothing)
    return [float(v) if np.isfinite(v) else float("inf") for v in values]


def _median(values) -> float:
    return float(np.median(values)) if len(values) else float("inf")


def _fit(model, records, discard, smoothing, max_steps):
    start = time.perf_counter()
    result = fit(
        model,
        records,
        discard=discard,
        smoothing=smoothing,
        max_steps=max_steps,
        progress=False,
    )
    return result, time.perf_counter() - start


def _summary(result, seconds) -> dict:
    return {
        "seconds": seconds,
        "loss": float(result.loss),
        "steps": int(result.num_steps),
        "converged": bool(result.converged),
        "reason": result.reason,
        "parameters": len(result.names),
        "train_median_nrmse": float(np.median(result.nrmse)),
    }


def run_auto(
    d, max_steps, starts=AUTO_STARTS, which="default", screen_folds=SCREEN_FOLDS
) -> dict:
    """`jaxmr fit --model auto` on the training records (`_select`'s call), with
    its default starts per fit unless `starts` says otherwise, its default
    candidates unless `which` (`AUTO_SETS`) says otherwise, and its screening's
    folds unless `screen_folds` does."""
    candidates = auto_candidates(d.train, which)
    lines = []
    start = time.perf_counter()
    selection = select_model(
        candidates,
        d.train,
        discard=d.train_discard,
        smoothing=d.train_smoothing,
        finalists=FINALISTS,
        max_steps=max_steps,
        screen_folds=screen_folds,
        log=lines.append,
        **({"starts": starts} if starts > 1 else {}),
    )
    seconds = time.perf_counter() - start
    held_out = _scores(selection.model, d.test, d.test_discard, d.test_smoothing)
    out = {
        "candidates": candidates,
        "starts": starts,
        "screen_folds": screen_folds,
        "choice": selection.name,
        "seconds": seconds,
        "held_out_nrmse": held_out,
        "held_out_median_nrmse": _median(held_out),
        "refit": _summary(selection.result, float("nan")),
        "ranking": [
            {
                "name": s.name,
                "stage": s.stage,
                "seconds": s.fit_time,
                "inner_held_out_median_nrmse": s.median_test_nrmse,
                # Per held-out record, pooled over the folds (the rule's input).
                "inner_held_out_nrmse": [float(v) for v in s.test_nrmse],
                "error": s.error,
            }
            for s in selection.scores
        ],
        "holdout": selection.holdout,
    }
    decision = selection.parsimony
    if decision is not None:  # the rule's inputs, to replay it with other tolerances
        out["parsimony"] = {
            "best": decision.best,
            "chosen": decision.chosen,
            "names": list(decision.names),
            "median_nrmse": list(decision.median_nrmse),
            "tolerance": decision.tolerance,
            "num_records": decision.num_records,
        }
    print(
        f"  auto: {selection.name} {out['held_out_median_nrmse']:.4f} "
        f"({seconds:.1f} s)",
        flush=True,
    )
    return out


def run_plain(d, name, max_steps) -> dict:
    """One candidate fitted from its template on the training records, as
    `jaxmr fit --model NAME` does, scored on the held-out records."""
    try:
        result, seconds = _fit(
            MODEL_TEMPLATES[name](d.train),
            d.train,
            d.train_discard,
            d.train_smoothing,
            max_steps,
        )
    except (ValueError, TypeError, RuntimeError, FloatingPointError) as e:
        return {"error": f"{type(e).__name__}: {e}", "held_out_median_nrmse": np.inf}
    held_out = _scores(result.model, d.test, d.test_discard, d.test_smoothing)
    out = _summary(result, seconds)
    out.update(held_out_nrmse=held_out, held_out_median_nrmse=_median(held_out))
    print(
        f"  plain {name}: {out['held_out_median_nrmse']:.4f} ({seconds:.1f} s, "
        f"{out['steps']} steps)",
        flush=True,
    )
    return out


def folds(d) -> dict:
    """Inner folds of the training records: (train, test) index lists."""
    n = len(d.train)
    *_, train_index, test_index = holdout_split(d.train, indices=True)
    out = {}
    if len(test_index) < n:  # a split by records (not in time)
        out["levels"] = (list(train_index), list(test_index))
    order = sorted(range(n), key=lambda k: d.train[k].name)
    held = sorted(order[1::3])
    if held and len(held) < n:
        out["records"] = ([k for k in range(n) if k not in held], held)
    return out


def run_cv(d, name, train_index, test_index, max_steps, screen_steps) -> dict:
    """One candidate on one inner fold: screened as `compare_models` screens (on the
    screening stretch, at most `screen_steps` steps), then fully fitted from there."""
    pick = lambda values, index: [values[k] for k in index]  # noqa: E731
    train, test = pick(d.train, train_index), pick(d.train, test_index)
    discard, smoothing = (
        pick(d.train_discard, train_index),
        pick(d.train_smoothing, train_index),
    )
    test_discard, test_smoothing = (
        pick(d.train_discard, test_index),
        pick(d.train_smoothing, test_index),
    )
    cut = [e.window(None, screening_end(e, w)) for e, w in zip(train, discard)]
    cut_test = [e.window(None, screening_end(e, w)) for e, w in zip(test, test_discard)]
    out = {}
    try:
        screened, seconds = _fit(
            MODEL_TEMPLATES[name](train), cut, discard, smoothing, screen_steps
        )
        out["screen"] = _summary(screened, seconds)
        out["screen"]["held_out_nrmse"] = _scores(
            screened.model, cut_test, test_discard, test_smoothing
        )
        full, seconds = _fit(screened.constrained, train, discard, smoothing, max_steps)
        out["full"] = _summary(full, seconds)
        out["full"]["held_out_nrmse"] = _scores(
            full.model, test, test_discard, test_smoothing
        )
    except (ValueError, TypeError, RuntimeError, FloatingPointError) as e:
        out["error"] = f"{type(e).__name__}: {e}"
    return out


def run_dataset(d, args) -> dict:
    print(
        f"{d.name}: {len(d.train)} training, {len(d.test)} held-out records", flush=True
    )
    out = {"summary": d.summary()}
    if not args.plain_only:
        out["auto"] = run_auto(
            d, args.max_steps, args.starts, args.auto_candidates, args.screen_folds
        )
    if args.auto_only:
        return out
    names = family_list(d.train)
    out["plain"] = {n: run_plain(d, n, args.max_steps) for n in names}
    best = min(names, key=lambda n: out["plain"][n]["held_out_median_nrmse"])
    best_score = out["plain"][best]["held_out_median_nrmse"]
    out["best"] = best
    out["best_held_out_median_nrmse"] = best_score
    if not args.plain_only:
        out["regret"] = out["auto"]["held_out_median_nrmse"] / best_score - 1
    return out


def run_cv_dataset(d, out, args) -> None:
    """The inner folds of `d` (into `out["cv"]`)."""
    names = list(out["plain"])
    out["cv"] = {}
    for fold, (train_index, test_index) in folds(d).items():
        out["cv"][fold] = {"train": train_index, "test": test_index}
        for n in names:
            r = run_cv(d, n, train_index, test_index, args.max_steps, args.screen_steps)
            out["cv"][fold][n] = r
            if "full" in r:
                print(
                    f"  {d.name} cv {fold} {n}: screen "
                    f"{_median(r['screen']['held_out_nrmse']):.4f} "
                    f"({r['screen']['seconds']:.1f} s), full "
                    f"{_median(r['full']['held_out_nrmse']):.4f} "
                    f"({r['full']['seconds']:.1f} s)",
                    flush=True,
                )


# --- the analysis: rules for select_model, chosen by leave-one-dataset-out ---------


def _complexity(name: str) -> tuple:
    """The parsimony order: family (simplest first), then no lag before lag, then
    straight laws before saturating ones (the library's order)."""
    return _select_complexity(name)


def _cv_table(result, fold_scheme, stage):
    """Per candidate, the pooled per-record inner held-out NRMSEs of the scheme's
    folds (`levels`, `records` or `both`), at `stage` (`screen` or `full`)."""
    cv = result.get("cv", {})
    fold_names = ["levels", "records"] if fold_scheme == "both" else [fold_scheme]
    fold_names = [f for f in fold_names if f in cv] or list(cv)
    table = {}
    for name in result["plain"]:
        values = []
        for f in fold_names:
            r = cv[f].get(name, {})
            if stage in r:
                values += r[stage]["held_out_nrmse"]
            else:
                values += [float("inf")] * len(cv[f]["test"])
        table[name] = np.array(values, float)
    return table


def choose(result, rule) -> str | None:
    """The candidate a selection `rule` picks from a dataset's inner folds.

    `rule`: (candidates, fold scheme, statistic, parsimony, finalists). Candidates
    missing from the dataset (a lag variant, when the input is constant) drop out.
    Screening ranks the candidates by their screened score; the best `finalists` are
    scored on full fits. Parsimony "1se": the simplest candidate whose score is
    within one standard error (of the paired per-record difference to the best) of
    the best; "none": the best.
    """
    candidates, scheme, statistic, parsimony, finalists = rule
    names = [c for c in candidates if c in result["plain"]]
    if not names or not result.get("cv"):
        return None
    full = _cv_table(result, scheme, "full")
    if finalists:
        screen = _cv_table(result, scheme, "screen")
        stat = lambda v: np.median(v) if statistic == "median" else np.mean(v)  # noqa: E731
        names = sorted(names, key=lambda n: stat(np.minimum(screen[n], 10.0)))[
            :finalists
        ]
    # Capped so that one diverged record does not make a mean infinite.
    scores = {n: np.minimum(full[n], 10.0) for n in names}
    stat = np.median if statistic == "median" else np.mean
    best = min(names, key=lambda n: stat(scores[n]))
    if parsimony == "none":
        return best
    within = []
    for n in names:
        diff = scores[n] - scores[best]
        se = np.std(diff, ddof=1) / np.sqrt(len(diff)) if len(diff) > 1 else 0.0
        if stat(scores[n]) - stat(scores[best]) <= se:
            within.append(n)
    return min(within, key=_complexity)


def regret_of(result, name) -> float:
    return (
        result["plain"][name]["held_out_median_nrmse"]
        / result["best_held_out_median_nrmse"]
        - 1
    )


# The candidate sets compared (each with its lag variants where the input varies):
# today's, and the families from the simplest one on.
CANDIDATE_SETS = {
    "today": ("bouc_wen", "spencer", "shear_thinning_spencer"),
    **{f"from_{FAMILIES[k]}": FAMILIES[k:] for k in range(4)},
    "without_lugre": (
        "bingham",
        "dahl",
        "bouc_wen",
        "spencer",
        "shear_thinning_spencer",
    ),
}


def _with_lag(families) -> tuple:
    return tuple(families) + tuple(f"{c}_lag" for c in families if f"{c}_lag" in LAGGED)


def rules():
    """The rules compared: the candidate sets of `CANDIDATE_SETS`, fold schemes,
    statistics, parsimony, and screening (finalists; 0 = every candidate fitted
    fully)."""
    for families in CANDIDATE_SETS.values():
        for scheme in ("levels", "records", "both"):
            for statistic in ("median", "mean"):
                for parsimony in ("none", "1se"):
                    for finalists in (0, 2, 3):
                        yield (
                            _with_lag(families),
                            scheme,
                            statistic,
                            parsimony,
                            finalists,
                        )


def analyse(results: dict) -> dict:
    """Leave-one-dataset-out: for each dataset, the rule with the lowest (max, then
    median) regret on the others, and the regret it gets on the left-out one."""
    names = [n for n, r in results.items() if r.get("cv")]
    if len(names) < 2:
        return {}
    table = {}
    for rule in rules():
        regrets = {}
        for n in names:
            chosen = choose(results[n], rule)
            regrets[n] = np.inf if chosen is None else regret_of(results[n], chosen)
        table[rule] = regrets

    def merit(rule, among):
        r = [table[rule][n] for n in among]
        # Ties: the larger candidate set (more families covered), fewer finalists.
        return (max(r), float(np.median(r)), -len(rule[0]), rule[4])

    lodo = {}
    for left in names:
        others = [n for n in names if n != left]
        rule = min(table, key=lambda r: merit(r, others))
        lodo[left] = {
            "rule": _rule_dict(rule),
            "choice": choose(results[left], rule),
            "regret": table[rule][left],
        }
    best_all = min(table, key=lambda r: merit(r, names))
    regrets = [v["regret"] for v in lodo.values()]
    # Named rules for the table: today's (default candidates, one levels fold, no
    # parsimony, 2 finalists) and the proposal candidates.
    named = {}
    for label, rule in {
        "today_like": (
            _with_lag(CANDIDATE_SETS["today"]),
            "levels",
            "median",
            "none",
            2,
        ),
        "all_families_both_1se_full": (_with_lag(FAMILIES), "both", "mean", "1se", 0),
        "all_families_both_1se_3_finalists": (
            _with_lag(FAMILIES),
            "both",
            "mean",
            "1se",
            3,
        ),
        "all_families_both_none_full": (_with_lag(FAMILIES), "both", "mean", "none", 0),
    }.items():
        r = table.get(rule)
        if r is None:
            continue
        named[label] = {
            "rule": _rule_dict(rule),
            "regret": r,
            "choices": {n: choose(results[n], rule) for n in names},
            "max_regret": max(r.values()),
            "median_regret": float(np.median(list(r.values()))),
        }
    return {
        "leave_one_dataset_out": lodo,
        "lodo_max_regret": max(regrets),
        "lodo_median_regret": float(np.median(regrets)),
        "best_rule_on_all": _rule_dict(best_all),
        "best_rule_on_all_regret": table[best_all],
        "named_rules": named,
        "oracle_regret_of_candidate_sets": {
            label: {
                n: min(
                    regret_of(results[n], c)
                    for c in _with_lag(families)
                    if c in results[n]["plain"]
                )
                for n in names
            }
            for label, families in CANDIDATE_SETS.items()
        },
    }


# The parsimony rules replayed on `select_model`'s pooled inner held-out errors: the
# statistic of a finalist's per-record NRMSEs ("mean"; "log": the mean log, i.e. the
# geometric mean, so that one badly fitted record weighs as a ratio; "median") and
# the tolerance, in standard errors of the paired per-record difference from the best
# (`select_model` today: "mean", 1).
STATISTICS = ("mean", "log", "median")
TOLERANCES = (0.0, 0.25, 0.5, 1.0, 2.0)
# "median" has no standard error here: its tolerance is a fraction of the best median
# (within 1 %, 2 %, 5 % of it).
MEDIAN_TOLERANCES = (0.0, 0.002, 0.01, 0.02, 0.05)  # 0.002: a tie (session 27)


def replay_parsimony(auto: dict, statistic: str, tolerance: float) -> str | None:
    """The finalist `select_model` would choose with another statistic and
    tolerance: the simplest (the library's parsimony order) whose statistic is within
    `tolerance` standard errors of the best one's. From the finalists' per-record
    inner held-out errors that `run_auto` saved, so no fit is repeated. ("median"
    has no standard error here: it takes the best.)"""
    finalists = [
        r
        for r in auto["ranking"]
        if r["stage"] == "full" and r.get("inner_held_out_nrmse")
    ]
    if not finalists:
        return None
    names = [r["name"] for r in finalists]
    errors = np.array([r["inner_held_out_nrmse"] for r in finalists], float)
    errors = np.where(np.isfinite(errors), errors, np.inf)
    finite = np.all(np.isfinite(errors), axis=1)
    if not finite.any():
        return None
    values = np.log(np.maximum(errors, 1e-12)) if statistic == "log" else errors
    stat = np.median if statistic == "median" else np.mean
    scores = np.array([stat(v) if f else np.inf for v, f in zip(values, finite)])
    best = int(np.argmin(scores))
    n = errors.shape[1]
    order = sorted(range(len(names)), key=lambda k: _select_complexity(names[k]))
    for k in order:
        if not finite[k]:
            continue
        if statistic == "median":
            if scores[k] <= (1 + tolerance) * scores[best]:
                return names[k]
            continue
        d = values[k] - values[best]
        se = np.std(d, ddof=1) / np.sqrt(n) if n >= 2 else 0.0
        if scores[k] - scores[best] <= tolerance * se:
            return names[k]
    return names[best]


def tolerance_analysis(results: dict) -> dict:
    """Leave-one-dataset-out over the parsimony rule (statistic, tolerance): for each
    dataset left out, the rule with the lowest (max, then median) regret on the
    others, and the regret its choice gets on the left-out dataset. A choice's
    regret is that of its plain fit (its template fitted on the training records
    with the defaults: the fit auto also runs, and keeps when its loss is lower)."""
    names = [
        n
        for n, r in results.items()
        if any(x.get("inner_held_out_nrmse") for x in r["auto"]["ranking"])
    ]
    if len(names) < 2:
        return {}
    rules = [
        (s, t)
        for s in STATISTICS
        for t in (MEDIAN_TOLERANCES if s == "median" else TOLERANCES)
    ]
    table = {}
    for rule in rules:
        row = {}
        for n in names:
            chosen = replay_parsimony(results[n]["auto"], *rule)
            row[n] = {
                "choice": chosen,
                "regret": np.inf
                if chosen is None or chosen not in results[n]["plain"]
                else regret_of(results[n], chosen),
            }
        table[rule] = row

    def merit(rule, among, second):
        r = [table[rule][n]["regret"] for n in among]
        # Ties: the larger tolerance (the simpler model), then the order above.
        return (max(r), float(second(r)), -rule[1], rules.index(rule))

    out = {"table": {f"{s} {t:g}": row for (s, t), row in table.items()}}
    # Two orders of merit on the other datasets: the worst regret, then the median
    # regret (as `analyse`) or the mean regret (the median is blind to small regrets
    # on a minority of datasets, which then leaves the tie to the tie-break).
    for label, second in (("median", np.median), ("mean", np.mean)):
        lodo = {}
        for left in names:
            others = [n for n in names if n != left]
            rule = min(rules, key=lambda r: merit(r, others, second))
            lodo[left] = {
                "statistic": rule[0],
                "tolerance": rule[1],
                **table[rule][left],
            }
        regrets = [v["regret"] for v in lodo.values()]
        best = min(rules, key=lambda r: merit(r, names, second))
        out[f"by_max_then_{label}"] = {
            "leave_one_dataset_out": lodo,
            "lodo_max_regret": max(regrets),
            "lodo_median_regret": float(np.median(regrets)),
            "rule_on_all": {"statistic": best[0], "tolerance": best[1]},
        }
    return out


def _rule_dict(rule) -> dict:
    candidates, scheme, statistic, parsimony, finalists = rule
    return {
        "candidates": list(candidates),
        "folds": scheme,
        "statistic": statistic,
        "parsimony": parsimony,
        "finalists": finalists,
    }


def _finish(figures: dict) -> dict:
    results = figures["datasets"]
    regrets = [r["regret"] for r in results.values()]
    figures["max_regret"] = max(regrets)
    figures["median_regret"] = float(np.median(regrets))
    # Which datasets the selection defaults were chosen on (the real ones always:
    # there is one of each) and which are fresh (simulated draws made after the
    # defaults were frozen), with the regret on the fresh ones alone.
    figures["datasets_used_in_choice"] = [n for n in results if gd.used_in_choice(n)]
    fresh = [n for n in results if not gd.used_in_choice(n)]
    figures["fresh_datasets"] = fresh
    if fresh:
        figures["fresh_max_regret"] = max(results[n]["regret"] for n in fresh)
        figures["fresh_median_regret"] = float(
            np.median([results[n]["regret"] for n in fresh])
        )
    figures["table"] = {
        n: {
            "auto_choice": r["auto"]["choice"],
            "auto_held_out": r["auto"]["held_out_median_nrmse"],
            "auto_seconds": r["auto"]["seconds"],
            "best": r["best"],
            "best_held_out": r["best_held_out_median_nrmse"],
            "regret": r["regret"],
            "plain": {
                c: [p["held_out_median_nrmse"], p.get("seconds")]
                for c, p in r["plain"].items()
            },
        }
        for n, r in results.items()
    }
    figures["analysis"] = analyse(results)
    figures["parsimony_tolerance"] = tolerance_analysis(results)
    return figures


def _run_separately(args) -> None:
    """`main` with `--separate`: each dataset (those of `--datasets`, or the
    default ones) in a fresh process with the same options, one after another, then
    `--analyse` of their files into `--json`."""
    if args.analyse or args.plain_only or args.json is None:
        raise SystemExit(
            "--separate needs --json and neither --analyse nor --plain-only"
        )
    names = (
        args.datasets.split(",")
        if args.datasets
        else (
            list(QUICK_DATASETS) if args.quick else gd.dataset_names((gd.FRESH_DRAW,))
        )
    )
    options = [f"--max-steps={args.max_steps}", f"--screen-steps={args.screen_steps}"]
    options += [f"--starts={args.starts}", f"--auto-candidates={args.auto_candidates}"]
    options += [f"--screen-folds={args.screen_folds}"]
    options += [flag for flag in ("quick", "small", "no_cv") if getattr(args, flag)]
    options = [o if o.startswith("--") else "--" + o.replace("_", "-") for o in options]
    with tempfile.TemporaryDirectory() as folder:
        parts = []
        for name in names:
            part = Path(folder) / f"gen_{len(parts)}.json"
            command = [sys.executable, __file__, *options, "--datasets", name]
            subprocess.run([*command, "--json", str(part)], check=True)
            parts.append(str(part))
        subprocess.run(
            [sys.executable, __file__, "--analyse", *parts, "--json", str(args.json)],
            check=True,
        )


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, help="write the figures here")
    parser.add_argument("--quick", action="store_true", help="a smoke run")
    parser.add_argument(
        "--small", action="store_true", help="--quick's records, all the steps"
    )
    parser.add_argument(
        "--datasets",
        help="comma-separated dataset names (default: utfsm, nees and the simulated "
        "draw FRESH_DRAW, drawn after the selection defaults were frozen)",
    )
    parser.add_argument("--no-cv", action="store_true", help="skip the inner folds")
    parser.add_argument(
        "--plain-only",
        action="store_true",
        help="only the plain fits (the yardstick of screening_choice.py): no "
        "selection, no inner folds, no analysis",
    )
    parser.add_argument(
        "--auto-only",
        action="store_true",
        help="only the selection (`starts_choice.py`): no plain fits, no inner "
        "folds, no analysis",
    )
    parser.add_argument(
        "--starts",
        type=int,
        default=AUTO_STARTS,
        help="starts per fit of the selection (default: jaxmr fit's)",
    )
    parser.add_argument(
        "--auto-candidates",
        choices=AUTO_SETS,
        default="default",
        help="the selection's candidates (default: jaxmr fit's); `today` and "
        "`saturating` are the options of saturation_choice_rule.md",
    )
    parser.add_argument("--max-steps", type=int, default=MAX_STEPS)
    parser.add_argument("--screen-steps", type=int, default=SCREEN_STEPS)
    parser.add_argument(
        "--screen-folds",
        choices=("every", "first"),
        default=SCREEN_FOLDS,
        help="the folds the selection screens every candidate on (default: jaxmr "
        "fit's); the options of screening_folds_rule.md",
    )
    parser.add_argument(
        "--analyse",
        type=Path,
        nargs="+",
        help="only analyse these JSON files (their datasets merged)",
    )
    parser.add_argument(
        "--separate",
        action="store_true",
        help="run every dataset in a process of its own (one process compiling "
        "every dataset's fits can run out of memory), then analyse them together",
    )
    args = parser.parse_args()
    if args.separate:
        _run_separately(args)
        return
    if args.analyse:
        parts = [json.loads(path.read_text()) for path in args.analyse]
        figures = parts[0]
        for part in parts[1:]:
            figures["datasets"].update(part["datasets"])
            # One process per dataset, one after another: the run is their sum.
            figures["seconds"] = figures["seconds"] + part["seconds"]
        write_figures(_finish(figures), args.json)
        return
    if args.quick:
        args.max_steps = min(args.max_steps, 30)
        args.screen_steps = min(args.screen_steps, 10)
    names = (
        args.datasets.split(",")
        if args.datasets
        else (
            list(QUICK_DATASETS) if args.quick else gd.dataset_names((gd.FRESH_DRAW,))
        )
    )
    start = time.perf_counter()
    figures = {
        "devices": len(jax.devices()),
        "load_average_at_start": os.getloadavg(),
        "quick": args.quick,
        "small": args.small,
        "max_steps": args.max_steps,
        "screen_steps": args.screen_steps,
        "screen_folds": args.screen_folds,
        "finalists": FINALISTS,
        "auto_candidates": list(AUTO_CANDIDATES),
        "auto_candidate_set": args.auto_candidates,
        "seed": gd.SEED,
        "draw_seeds": list(gd.DRAW_SEEDS),
        "noise": {
            "white": gd.WHITE_NOISE,
            "ar1": gd.AR_NOISE,
            "ar1_phi": gd.AR_PHI,
            "motion": gd.MOTION_NOISE,
        },
        "datasets": {},
    }

    def save():  # after every dataset: a long run can be read as it goes
        figures["seconds"] = time.perf_counter() - start
        if args.json:
            args.json.parent.mkdir(parents=True, exist_ok=True)
            args.json.write_text(json.dumps(figures, indent=1, default=float))

    # First the selection and the plain fits of every dataset, then the inner folds.
    data = gd.datasets(names, quick=args.quick or args.small)
    for d in data:
        figures["datasets"][d.name] = run_dataset(d, args)
        save()
    if args.plain_only or args.auto_only:
        write_figures(figures, args.json)
        return
    if not args.no_cv:
        for d in data:
            run_cv_dataset(d, figures["datasets"][d.name], args)
            save()
    write_figures(_finish(figures), args.json)


if __name__ == "__main__":
    main()
