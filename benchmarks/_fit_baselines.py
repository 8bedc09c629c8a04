"""scipy's `least_squares` on a jaxmr residual at equal accuracy, and the clocks that
time a fit with and without its compilation: the identification baselines of
`identify_speed.py` and `boucwen_benchmark.py` (issue 28).

The rule (equal accuracy): jaxmr's fit runs first, to its own stop; its final loss
$L$ (½ Σ r² of the weighted residual r) sets the target $L\\,(1 + 10^{-3})$, far
below what the noise makes significant. Each fit's time is the wall time from its
call (data packing, tracing and compilation included) to the first point whose loss
reaches the target: jaxmr's best loss after a step (its `progress` callback), any
residual evaluation of scipy's (those of its finite differences included: their
points lie within ~1e-8 of an iterate). A baseline stops there, or when it has used
`budget` seconds, or at its own tolerance; one that never reached the target is
marked `reached: false` and its time (a lower bound) is the time it ran.

Each fit runs in a fresh interpreter (`in_fresh_process`), so that none reuses what
another compiled or traced, with JAX's persistent compilation cache off, and its
compilation is measured there (`CompileClock`): the union of JAX's tracing, lowering
and XLA compilation intervals (`jax.monitoring`'s time spans; nested traces counted
once) up to the fit's target. Excluding compilation, a time is that wall time less
the compilation within it.
"""

import concurrent.futures
import multiprocessing
import time
from collections.abc import Callable

import numpy as np

# JAX's events for tracing a function, lowering it to MLIR and compiling it with XLA
# (a persistent cache's read counts as the latter).
COMPILE_EVENTS = (
    "/jax/core/compile/jaxpr_trace_duration",
    "/jax/core/compile/jaxpr_to_mlir_module_duration",
    "/jax/core/compile/backend_compile_duration",
)
# The target loss over the best fit's final loss.
TARGET = 1 + 1e-3


def in_fresh_process(function: Callable, *args, **kwargs):
    """`function(*args, **kwargs)` in a new Python interpreter (spawned), its result
    returned (it must pickle). `function` must be importable by its module's name
    (a module-level function of a benchmark script)."""
    context = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(1, mp_context=context) as pool:
        return pool.submit(function, *args, **kwargs).result()


def cold_jax() -> None:
    """The first call of a fresh process's work: jaxmr's CPU settings (as `jaxmr fit`
    and the benchmarks' own processes use), double precision, and no persistent
    compilation cache (a cold start is measured)."""
    import jaxmr

    jaxmr.devices.configure_cpu()
    import jax

    jax.config.update("jax_enable_x64", True)
    jax.config.update("jax_enable_compilation_cache", False)


class CompileClock:
    """Records JAX's tracing, lowering and compilation intervals (wall clock,
    `time.time()`) while registered; `seconds(until)` is the length of their union
    up to `until`. A context manager."""

    def __init__(self):
        self.spans: list[tuple[float, float]] = []

    def _record(self, event, start, end, **kwargs):
        if event in COMPILE_EVENTS:
            self.spans.append((start, end))

    def __enter__(self):
        import jax.monitoring

        jax.monitoring.register_event_time_span_listener(self._record)
        return self

    def __exit__(self, *exc_info):
        import jax.monitoring

        jax.monitoring.unregister_event_time_span_listener(self._record)
        return False

    def seconds(self, until: float = np.inf) -> float:
        total, reach = 0.0, -np.inf
        for start, end in sorted(self.spans):
            end = min(end, until)
            start = max(start, reach)
            if end > start:
                total += end - start
                reach = end
        return total


class LossTrace:
    """(time since `started` [s], loss) pairs, the time from `time.time()`; and the
    process's CPU time (`time.process_time()`: every thread's, since the trace was
    made) at each pair, in `cpu`."""

    def __init__(self, started: float):
        self.started = started
        self.points: list[tuple[float, float]] = []
        self.cpu: list[float] = []
        self._cpu_started = time.process_time()

    def add(self, loss: float) -> None:
        self.points.append((time.time() - self.started, float(loss)))
        self.cpu.append(time.process_time() - self._cpu_started)

    def cpu_to(self, target: float) -> float:
        """The CPU time when the loss was first at most `target`, or at the last
        point where it never was."""
        if len(self.cpu) != len(self.points):  # a trace rebuilt from its points
            return float("nan")
        for (_, loss), cpu in zip(self.points, self.cpu, strict=True):
            if loss <= target:
                return cpu
        return self.cpu[-1] if self.cpu else 0.0

    def time_to(self, target: float) -> float | None:
        """The first time the loss was at most `target`, or None."""
        for t, loss in self.points:
            if loss <= target:
                return t
        return None

    def best(self) -> float:
        return min((loss for _, loss in self.points), default=np.inf)


class _Stop(Exception):
    """Raised from inside scipy's callbacks: target reached or budget spent."""


def timed_figures(
    trace: LossTrace, clock: CompileClock, target: float, total: float
) -> dict:
    """A fit's time to `target` (or its whole `total` where it never got there) and
    the compilation within it [s]."""
    reached = trace.time_to(target)
    seconds = total if reached is None else reached
    compile_seconds = clock.seconds(until=trace.started + seconds)
    return {
        "reached": reached is not None,
        "seconds": seconds,
        "compile_seconds": compile_seconds,
        "seconds_excluding_compile": seconds - compile_seconds,
        # Every thread's: jaxmr's may use several cores where scipy's loop uses one.
        "cpu_seconds": trace.cpu_to(target),
        "total_seconds": total,
        "best_loss": trace.best(),
    }


def scipy_to_target(
    build: Callable,
    *,
    method: str,
    exact: bool,
    target: float,
    budget: float,
    max_nfev: int | None = None,
) -> dict:
    """scipy's `least_squares` (`method` "trf" or "lm", `x_scale="jac"`, scipy's
    default tolerances) on the residual `build()` makes, with a 2-point
    finite-difference Jacobian or (`exact`) `jax.jacfwd` of the same residual, both
    jitted (`eqx.filter_jit`), until the target or the budget [s].

    `build()` returns `(residual, x0, args)`: `residual(x, *args)` of the flat
    parameter vector (a JAX array) and the data `args` it takes as arguments (as
    `fit` passes its data: they are not compiled in), not yet jitted, and the start;
    it is called inside the timing (its data packing, like `fit`'s, is part of the
    fit). Returns the figures of `timed_figures`, the evaluations made, why it
    stopped, and `x`: the point of its lowest loss (a list).
    """
    import equinox as eqx
    import jax
    import jax.numpy as jnp
    import scipy.optimize

    counts = {"residuals": 0, "jacobians": 0}
    best = {"loss": np.inf, "x": None}
    with CompileClock() as clock:
        started = time.time()
        trace = LossTrace(started)
        residual, x0, args = build()
        residual_jit = eqx.filter_jit(residual)
        jacobian_jit = eqx.filter_jit(
            lambda x, *a: jax.jacfwd(lambda x: residual(x, *a))(x)
        )

        def check_budget():
            if time.time() - started > budget:
                raise _Stop("budget")

        def fun(x):
            check_budget()
            r = np.asarray(residual_jit(jnp.asarray(x), *args))
            counts["residuals"] += 1
            loss = 0.5 * float(r @ r) if np.all(np.isfinite(r)) else np.inf
            trace.add(loss)
            if loss < best["loss"]:
                best.update(loss=loss, x=np.array(x, dtype=float))
            if loss <= target:
                raise _Stop("target")
            return r

        def jac(x):
            check_budget()
            counts["jacobians"] += 1
            return np.asarray(jacobian_jit(jnp.asarray(x), *args))

        try:
            solution = scipy.optimize.least_squares(
                fun,
                np.asarray(x0, dtype=float),
                jac=jac if exact else "2-point",
                method=method,
                x_scale="jac",
                max_nfev=max_nfev,
            )
            stop = f"scipy: {solution.message}"
        except _Stop as e:
            stop = str(e)
        total = time.time() - started
    x = best["x"] if best["x"] is not None else np.asarray(x0, dtype=float)
    return {
        "method": method,
        "exact": exact,
        "jacobian": "jax.jacfwd (exact)" if exact else "2-point finite differences",
        "stop": stop,
        **timed_figures(trace, clock, target, total),
        "residual_evaluations": counts["residuals"],
        "jacobian_evaluations": counts["jacobians"] if exact else None,
        "x": [float(v) for v in x],
    }


def speedups(jaxmr: dict, baselines: dict[str, dict], prefix: str) -> dict:
    """`speedup_<prefix>_fd` and `speedup_<prefix>_exact_jacobian`, each with its
    `_excluding_compile`: the fastest baseline of each kind (scipy's methods, best
    of) over jaxmr, each to the target; `..._lower_bound` where that baseline never
    reached it (its time is the budget or its own stop); `..._cpu_time`: the same
    baseline's CPU time over jaxmr's (every thread's, compilation included: the cost
    in core-seconds where jaxmr uses several cores)."""
    out = {}
    for kind, exact in (("fd", False), ("exact_jacobian", True)):
        runs = [b for b in baselines.values() if b["exact"] == exact]
        if not runs:
            continue
        best = min(runs, key=lambda b: b["seconds"])
        name = f"speedup_{prefix}_{kind}"
        out[name] = best["seconds"] / jaxmr["seconds"]
        out[f"{name}_excluding_compile"] = (
            best["seconds_excluding_compile"] / jaxmr["seconds_excluding_compile"]
        )
        if "cpu_seconds" in best and "cpu_seconds" in jaxmr:
            out[f"{name}_cpu_time"] = best["cpu_seconds"] / jaxmr["cpu_seconds"]
        out[f"{name}_method"] = best["method"]
        out[f"{name}_lower_bound"] = not best["reached"]
    return out
