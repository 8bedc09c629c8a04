"""Gradient tuning of controllers (and passive parameters) through the closed loop."""

import dataclasses
import functools
import time
from collections.abc import Callable, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._closed_loop import SystemSolution, simulate_system
from ._control.base import AbstractController
from ._metrics import wk_rms
from ._systems.base import AbstractSystem


def comfort(solution: SystemSolution) -> jax.Array:
    """ISO 2631-1 Wk-weighted RMS body acceleration $a_w$ [m/s²] of one run."""
    return wk_rms(solution["body_acceleration"], solution.dt)


@dataclasses.dataclass(frozen=True, eq=False)
class TuneResult:
    """The outcome of `tune` or `random_search`.

    **Attributes:**

    - `system`, `controller`: the tuned pair (the controller's `temperature`, if it has
      one, restored to its value before tuning: evaluate the hard law).
    - `values`: the tuned parameters, in the order `parameters` returns them.
    - `loss`: the best training loss (mean objective over the training roads).
    - `initial_loss`: the loss at the start.
    - `history`: the best loss after each iteration.
    - `simulations`: road simulations spent (a gradient evaluation of a batch of $B$
      roads counts $B$, like $B$ forward runs, although its backward pass costs
      about twice a forward run more).
    - `seconds`: wall time, compilation included.
    - `reason`: why it stopped.
    """

    system: AbstractSystem
    controller: AbstractController
    values: tuple
    loss: float
    initial_loss: float
    history: tuple[float, ...]
    simulations: int
    seconds: float
    reason: str


def _batch_loss(pair, roads, objective, duration, dt, substeps, delay):
    system, controller = pair

    def one(road):
        sol = simulate_system(
            system,
            road,
            controller,
            duration,
            dt=dt,
            substeps=substeps,
            delay=delay,
            throw=False,
        )
        value = objective(sol)
        # A run that failed (diverged, left the current range) scores badly instead of
        # poisoning the mean with nan.
        return jnp.where(jnp.isfinite(value), value, 1e6)

    return jnp.mean(eqx.filter_vmap(one)(roads))


def _log_loss(
    log_values,
    pair,
    log_space,
    parameters,
    roads,
    objective,
    duration,
    dt,
    substeps,
    delay,
):
    pair = eqx.tree_at(parameters, pair, _to_values(log_values, log_space))
    return _batch_loss(pair, roads, objective, duration, dt, substeps, delay)


_loss_and_grad = eqx.filter_jit(eqx.filter_value_and_grad(_log_loss))
_loss = eqx.filter_jit(_log_loss)


def _set_temperature(controller, temperature):
    if temperature is None or not hasattr(controller, "temperature"):
        return controller
    value = jnp.asarray(temperature, dtype=jnp.result_type(controller.temperature))
    return eqx.tree_at(lambda c: c.temperature, controller, value)


# The optimiser's variables u and the parameters: `space` is False (u = value), True
# (u = log value) or a tuple of (low, high) bounds per parameter (value = exp(log low +
# (log high - log low) sigmoid(u)), inside the bounds whatever u).
def _to_values(us, space):
    if space is False:
        return tuple(us)
    if space is True:
        return tuple(jnp.exp(u) for u in us)
    return tuple(
        jnp.exp(np.log(lo) + (np.log(hi) - np.log(lo)) * jax.nn.sigmoid(u))
        for u, (lo, hi) in zip(us, space, strict=True)
    )


def _from_values(values, space):
    if space is False:
        return tuple(values)
    if space is True:
        return tuple(jnp.log(v) for v in values)
    out = []
    for v, (lo, hi) in zip(values, space, strict=True):
        p = (jnp.log(v) - np.log(lo)) / (np.log(hi) - np.log(lo))
        if not np.all((np.asarray(p) > 0) & (np.asarray(p) < 1)):
            raise ValueError(
                f"tune: a starting value {v} lies outside its bounds ({lo}, {hi})."
            )
        out.append(jnp.log(p / (1 - p)))
    return tuple(out)


def _initial(pair, parameters, log_space=True) -> tuple:
    values = tuple(jnp.asarray(v) for v in parameters(pair))
    for v in values if log_space else ():
        if not np.all(np.asarray(v) > 0):
            raise ValueError(
                "tune: every tuned parameter must be positive (they are optimised in "
                f"log space, as gains and damping coefficients are), got {v}."
            )
    return values


@functools.lru_cache(maxsize=64)
def _as_tuple_where(parameters):
    # Cached on the user's function, so repeated calls with it reuse the compiled loss
    # (the wrapper is a static argument of the jitted functions).
    def where(pair):
        leaves = parameters(pair)
        return tuple(leaves) if isinstance(leaves, (tuple, list)) else (leaves,)

    return where


def _check(system, controller, roads):
    if not isinstance(system, AbstractSystem):
        raise TypeError(
            f"`system` must be a jaxmr system, got {type(system).__name__}."
        )
    if not isinstance(controller, AbstractController):
        raise TypeError(
            f"`controller` must be a jaxmr controller, got {type(controller).__name__}."
        )
    sizes = {x.shape[0] for x in jax.tree.leaves(roads) if eqx.is_array(x) and x.ndim}
    if len(sizes) != 1:
        raise ValueError(
            "`roads` must be a batch of road signals with one leading axis (e.g. "
            "`jax.vmap(lambda k: jaxmr.iso8608_road('C', 20.0, 10.0, k))(keys)`)."
        )
    return sizes.pop()


def tune(
    system: AbstractSystem,
    controller: AbstractController,
    roads,
    duration: float,
    *,
    parameters: Callable,
    objective: Callable[[SystemSolution], jax.Array] = comfort,
    temperature: float | None = None,
    steps: int = 40,
    learning_rate: float = 0.1,
    patience: int = 10,
    dt: float = 1e-3,
    substeps: int = 4,
    delay: int = 1,
    log_space: bool = True,
    bounds: Sequence[tuple[float, float]] | None = None,
    progress: bool | Callable = True,
) -> TuneResult:
    r"""Tune controller gains (and passive parameters) by gradient descent through the
    closed-loop simulation, averaged over a batch of roads.

    Minimises $\frac1B \sum_b J(\text{simulate\_system}(\ldots, \text{road}_b))$ over
    the parameters `parameters` selects, in log space (they stay positive and a step
    is relative), with Adam and exact reverse-mode gradients through the whole loop
    (the roads run together under `vmap`). A switching law's gains that appear only
    in its switching condition have zero gradient with the hard law: give a
    `temperature` > 0 to tune its smooth relaxation; the result carries the hard law
    (the controller's own temperature) for evaluation. Keeps the best parameters; stops
    after `steps`, or `patience` steps without improvement, or on Ctrl-C.

    **Arguments:**

    - `system`, `controller`: the starting pair.
    - `roads`: a batch of excitation signals (one leading axis), the training set.
    - `duration`: simulated time per road [s].
    - `parameters`: `lambda pair: (pair[1].gain, ...)` selecting the tuned leaves of
      `(system, controller)` (the `eqx.tree_at` convention); each must be positive.
    - `objective`: per-run loss from a `SystemSolution` (default `comfort`: Wk-weighted
      RMS body acceleration [m/s²]); add penalties for constraints here.
    - `temperature`: the relaxation used while tuning (`None`: the controller's own).
    - `steps`, `learning_rate` (Adam, in log space: 0.1 ≈ 10 % per step),
      `patience`.
    - `dt`, `substeps`, `delay`: as `simulate_system`.
    - `log_space`: optimise the logarithms (default: positive parameters, relative
      steps); `False` optimises the values themselves (e.g. `CurrentSchedule.logits`).
    - `bounds`: optional `(low, high)` per parameter (positive), e.g. an on-current
      within the damper's range or a blend in (0, 1]: the parameter is then mapped
      from an unbounded variable through a sigmoid in log space.
    - `progress`: print a line per step (True), nothing (False), or a callable
      `progress(step, loss)`.

    **Returns:** a `TuneResult`.
    """
    batch = _check(system, controller, roads)
    where = _as_tuple_where(parameters)
    hard = controller
    pair = (system, _set_temperature(controller, temperature))
    space = log_space
    if bounds is not None:
        if not log_space:
            raise ValueError("tune: `bounds` need `log_space=True`.")
        space = tuple((float(lo), float(hi)) for lo, hi in bounds)
        if any(not 0 < lo < hi for lo, hi in space):
            raise ValueError(f"tune: `bounds` must be 0 < low < high, got {bounds}.")
    log_values = _from_values(_initial(pair, where, log_space), space)
    args = (space, where, roads, objective, duration, dt, substeps, delay)
    report = _printer(progress)
    m = tuple(jnp.zeros_like(v) for v in log_values)
    s = tuple(jnp.zeros_like(v) for v in log_values)
    beta1, beta2, eps = 0.9, 0.999, 1e-12
    start = time.perf_counter()
    best, best_loss, initial, history = log_values, np.inf, None, []
    reason, since = f"reached steps = {steps}", 0
    simulations = 0
    try:
        for k in range(1, steps + 1):
            loss, grads = _loss_and_grad(log_values, pair, *args)
            simulations += batch
            loss = float(loss)
            initial = loss if initial is None else initial
            if np.isfinite(loss) and loss < best_loss:
                best, best_loss, since = log_values, loss, 0
            else:
                since += 1
            history.append(best_loss)
            report(k, best_loss)
            if since >= patience:
                reason = f"stalled: no improvement in {patience} steps"
                break
            m = tuple(beta1 * a + (1 - beta1) * g for a, g in zip(m, grads))
            s = tuple(beta2 * a + (1 - beta2) * g**2 for a, g in zip(s, grads))
            log_values = tuple(
                v
                - learning_rate
                * (a / (1 - beta1**k))
                / (jnp.sqrt(b / (1 - beta2**k)) + eps)
                for v, a, b in zip(log_values, m, s)
            )
    except KeyboardInterrupt:
        reason = f"interrupted at step {len(history) + 1}; the best parameters are kept"
    values = _to_values(best, space)
    tuned_system, tuned = eqx.tree_at(where, (system, hard), values)
    return TuneResult(
        system=tuned_system,
        controller=tuned,
        values=values,
        loss=float(best_loss),
        initial_loss=float(initial if initial is not None else np.nan),
        history=tuple(history),
        simulations=simulations,
        seconds=time.perf_counter() - start,
        reason=reason,
    )


def random_search(
    system: AbstractSystem,
    controller: AbstractController,
    roads,
    duration: float,
    *,
    parameters: Callable,
    simulations: int,
    objective: Callable[[SystemSolution], jax.Array] = comfort,
    spread: float = 10.0,
    bounds: Sequence[tuple[float, float]] | None = None,
    key: jax.Array | None = None,
    dt: float = 1e-3,
    substeps: int = 4,
    delay: int = 1,
) -> TuneResult:
    """The derivative-free baseline for `tune`: evaluate log-uniform random parameter
    sets within a factor `spread` of the start (the start included; clipped to `bounds`
    when given) on the same training roads, with the hard law, until `simulations`
    road simulations are spent; keep the best.

    **Arguments:** as `tune`, plus `simulations` (the budget: give `tune`'s
    `TuneResult.simulations` for an equal-budget comparison), `spread`, `key`.
    """
    batch = _check(system, controller, roads)
    where = _as_tuple_where(parameters)
    pair = (system, controller)
    log0 = tuple(jnp.log(v) for v in _initial(pair, where))
    args = (True, where, roads, objective, duration, dt, substeps, delay)
    trials = max(1, simulations // batch)
    key = jax.random.key(0) if key is None else key
    start = time.perf_counter()
    best, best_loss, history, initial = log0, np.inf, [], None
    for j in range(trials):
        if j == 0:
            candidate = log0
        else:
            key, *keys = jax.random.split(key, len(log0) + 1)
            candidate = tuple(
                v + jax.random.uniform(k_, v.shape, v.dtype, -1, 1) * np.log(spread)
                for v, k_ in zip(log0, keys)
            )
            if bounds is not None:
                candidate = tuple(
                    jnp.clip(v, np.log(lo), np.log(hi))
                    for v, (lo, hi) in zip(candidate, bounds, strict=True)
                )
        loss = float(_loss(candidate, pair, *args))
        initial = loss if initial is None else initial
        if np.isfinite(loss) and loss < best_loss:
            best, best_loss = candidate, loss
        history.append(best_loss)
    values = tuple(jnp.exp(v) for v in best)
    tuned_system, tuned = eqx.tree_at(where, pair, values)
    return TuneResult(
        system=tuned_system,
        controller=tuned,
        values=values,
        loss=float(best_loss),
        initial_loss=float(initial),
        history=tuple(history),
        simulations=trials * batch,
        seconds=time.perf_counter() - start,
        reason=f"budget of {trials * batch} simulations spent",
    )


def evaluate(
    system: AbstractSystem,
    controller: AbstractController,
    roads,
    duration: float,
    metrics: dict[str, Callable[[SystemSolution], jax.Array]] | None = None,
    *,
    dt: float = 1e-3,
    substeps: int = 4,
    delay: int = 1,
) -> dict[str, np.ndarray]:
    """Every metric of every road (a batch, one leading axis), e.g. on held-out seeds.

    **Arguments:** as `tune`; `metrics` maps names to per-run functions of a
    `SystemSolution` (default: `{"comfort": comfort}`).

    **Returns:** `{name: array of one value per road}`.
    """
    metrics = {"comfort": comfort} if metrics is None else dict(metrics)
    return {
        name: np.asarray(value)
        for name, value in _evaluate(
            system,
            controller,
            roads,
            duration,
            tuple(metrics.items()),
            dt,
            substeps,
            delay,
        ).items()
    }


@eqx.filter_jit
def _evaluate(
    system, controller, roads, duration, metrics: Sequence, dt, substeps, delay
):
    def one(road):
        sol = simulate_system(
            system, road, controller, duration, dt=dt, substeps=substeps, delay=delay
        )
        return {name: fn(sol) for name, fn in metrics}

    return eqx.filter_vmap(one)(roads)


def _printer(progress):
    if callable(progress):
        return progress
    if not progress:
        return lambda step, loss: None

    def report(step, loss):
        print(f"  tune step {step:3d}: loss {loss:.6g}", flush=True)

    return report
