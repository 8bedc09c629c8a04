"""`tune`: gradient descent through the closed loop, with annealed relaxations."""

import time
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from .._closed_loop import Sampling, SystemSolution, loop_settings
from .._control.base import AbstractController
from .._control.sensors import Sensors
from .._control.smooth import temperatures
from .._distribute import batch_mesh, replicate, to_host
from .._integrate import FixedStep
from .._systems.base import AbstractSystem
from .common import (
    chooses_steps,
    own_sampling,
    prepare,
    printer,
    sensor_noise,
    set_temperature,
    tune_result,
)
from .loss import comfort, loss_and_grad, losses
from .result import TuneResult


def _geometric(value, steps: int, name: str) -> np.ndarray:
    """A number at every step, or a `(start, end)` pair decayed geometrically."""
    if isinstance(value, (tuple, list)):
        if len(value) != 2 or not 0 < value[1] <= value[0]:
            raise ValueError(
                f"tune: an annealed `{name}` is (start, end) with start >= end > 0, "
                f"got {value}."
            )
        start, end = (float(v) for v in value)
        return start * (end / start) ** (np.arange(steps) / max(steps - 1, 1))
    return np.full(steps, float(value))


def _schedule(temperature, controller, steps: int) -> np.ndarray | None:
    """The relaxation temperature at each step, or None for the hard law only."""
    # Every law with a relaxation, wrapped ones (ObserverBasedController.law)
    # included: what `with_temperature` sets.
    own = temperatures(controller)
    if not own:
        if temperature not in (None, 0, 0.0):
            raise ValueError(
                f"tune: {type(controller).__name__} has no `temperature` to relax."
            )
        return None
    if temperature is None:
        temperature = max(float(np.max(np.asarray(t))) for t in own)
    if isinstance(temperature, (tuple, list)):
        return _geometric(temperature, steps, "temperature")
    temperature = float(temperature)
    if temperature < 0:
        raise ValueError(f"tune: `temperature` must be >= 0, got {temperature}.")
    return None if temperature == 0 else np.full(steps, temperature)


_BETA1, _BETA2, _EPS = 0.9, 0.999, 1e-12  # Adam's moment decays and its floor


@jax.jit
def _adam(u, m, s, grads, rate, t):
    """One Adam step of the parameters `u` (a tuple of arrays) with moments `m`, `s`
    at step `t` (1, 2, ...) and learning rate `rate`: `(u, m, s)` after it. One
    compiled program (eagerly, each of its dozen element-wise operations compiled on
    its own: about 2 s of a first `tune`)."""
    m = tuple(_BETA1 * a + (1 - _BETA1) * g for a, g in zip(m, grads))
    s = tuple(_BETA2 * a + (1 - _BETA2) * g**2 for a, g in zip(s, grads))
    u = tuple(
        v - rate * (a / (1 - _BETA1**t)) / (jnp.sqrt(b / (1 - _BETA2**t)) + _EPS)
        for v, a, b in zip(u, m, s)
    )
    return u, m, s


def tune(
    system: AbstractSystem,
    controller: AbstractController,
    roads,
    duration: float,
    *,
    parameters: Callable,
    objective: Callable[[SystemSolution], jax.Array] = comfort,
    temperature: float | tuple[float, float] | None = None,
    steps: int = 40,
    learning_rate: float | tuple[float, float] = 0.1,
    patience: int = 10,
    check_every: int = 5,
    validation=None,
    samples: AbstractSystem | None = None,
    worst_share: float = 1.0,
    sensors: Sensors | str | None = None,
    sensor_key: jax.Array | None = None,
    sampling: Sampling | None = None,
    integrator: FixedStep | None = None,
    log_space: bool | Sequence[bool] = True,
    bounds: Sequence[tuple[float, float] | None] | None = None,
    progress: bool | Callable = True,
    **deprecated,
) -> TuneResult:
    r"""Tune controller parameters (and passive ones) by gradient descent through the
    closed-loop simulation, averaged over a batch of roads.

    Minimises $\frac1B \sum_b J(\text{simulate\_system}(\ldots, \text{road}_b))$ over
    the parameters `parameters` selects, with Adam and exact reverse-mode gradients
    through the whole loop (the roads run together under `vmap`, each differentiated
    on its own so that a diverged road drops out of the gradient instead of turning
    it into NaN).

    A semi-active law switches and clips, so its hard loss is flat or rippled in its
    gains: gradients are taken of its smooth relaxation (`temperature` > 0, see
    `jaxmr.with_temperature`), best annealed from soft to nearly hard, e.g.
    `temperature=(0.3, 0.01)` (geometric over the steps; each relaxation's force
    scale is the damper's own yield force, so one temperature fits every device).
    What is kept is always judged on the hard law: its training loss is evaluated
    every `check_every` steps and at the end, and the best of these is returned. A
    law without relaxation (a constant current, a schedule) is judged at every step.
    Stops after `steps`, or after `patience` steps in which neither the hard law's best
    nor the relaxed loss improved, or on Ctrl-C.

    **Arguments:**

    - `system`, `controller`: the starting pair.
    - `roads`: a batch of excitation signals (one leading axis), the training set.
    - `duration`: simulated time per road [s].
    - `parameters`: `lambda pair: (pair[1].c_sky, ...)` selecting the tuned leaves of
      `(system, controller)` (the `eqx.tree_at` convention), or a list of arrays
      (e.g. every weight of a `NeuralFeedback`).
    - `objective`: per-run loss from a `SystemSolution` (default `comfort`:
      Wk-weighted RMS body acceleration [m/s²]); add penalties for constraints here.
    - `temperature`: the relaxation while tuning (dimensionless): a number, a
      `(start, end)` pair to anneal, or `None` for the controller's own.
    - `steps`, `learning_rate` (Adam: 0.1 is about 10 % per step in log space; a
      `(start, end)` pair decays it geometrically over the steps: long strides while
      far from an optimum, fine ones near it),
      `patience` (in steps), `check_every` (steps between hard-law checks).
    - `validation`: held-out roads; the returned pair's mean objective on them is
      `TuneResult.held_out_loss`.
    - `samples`: a batch of systems (one leading axis: damper parameters drawn from a
      fit's covariance, `FitResult.sample`) to tune over instead of `system`
      alone: the loss is the mean over every sample and road (robust tuning). The
      tuned parameters are set in every sample.
    - `worst_share`: with `samples`, the loss is the mean over the worst
      `worst_share` of the samples (each sample's loss its mean over the roads): the
      conditional value at risk (CVaR) of the spread. 1 (default) is the mean over
      every sample; $1/S$ of $S$ samples the worst one alone; 0.3 the worst 30 %.
      Worst-case tuning: a law that must hold on every unit, not on the average one.
    - `sensors`: what the controller reads, as in `simulate_system`: `None`
      (default: perfect readings but no device, so that a law that inverts the
      damper must run inside an `ObserverBasedController` with its own
      `DamperObserver`), `"oracle"` (perfect information, the device's true state
      included: for research comparisons only) or a `Sensors` set (e.g.
      `realistic_sensors(system)`), the law then inside an `ObserverBasedController`
      whose estimator and observer can be tuned with it
      (`ObserverBasedController.tunable`).
    - `sensor_key`: the `jax.random` key of the sensors' noise, required with
      `sensors`. Each gradient step draws fresh noise on every road (the gradient is
      taken through the sampled noise: a stochastic gradient over the noise, as over
      the roads); the hard-law checks, the losses reported and the held-out loss
      read one fixed draw, road $i$'s from `jax.random.fold_in(sensor_key, i)`,
      as `evaluate` draws it, so that every comparison is paired (a law tuned
      without relaxation is judged on its gradient's own loss, so its steps read
      that fixed draw too). Every damper sample reads its road's noise.
    - `sampling`, `integrator`: the controller's timing (a `Sampling`) and the RK4
      steps per sample (a `FixedStep`), as in `simulate_system`, whose defaults they
      share (an `ObserverBasedController`'s own `sampling` when none is given); the
      deprecated `dt`, `substeps` and `delay` still work, as there. With no
      `integrator`, the substeps are chosen as `simulate_system` chooses them, from
      the damper's stiffness, for the stiffest run of the starting pair (each road,
      each damper sample, simulated once before tuning): `FixedStep()` where the
      damper is not stiff, else the power of two of substeps that keeps RK4 stable,
      `ValueError` with what to change where even the most (1024) diverge. The
      choice holds for the whole run (`TuneResult.integrator`); a parameter set
      that drives its runs unstable later scores inf and is left behind. Where
      every parameter set tried fails, `ValueError` says what to change.
    - `log_space`: optimise logarithms (default: positive parameters, relative
      steps); `False` optimises the values (signed weights, `CurrentSchedule.logits`);
      or one bool per parameter (signed weights tuned with positive filter corners).
    - `bounds`: optional `(low, high)` per parameter (positive; `None` for an
      unbounded one): the parameter is then mapped from an unbounded variable
      through a sigmoid in log space.
    - `progress`: a line per step (True), nothing (False), or `progress(step, loss)`.

    **Returns:** a `TuneResult`.
    """
    sampling = own_sampling(controller, sampling, deprecated)
    chosen = chooses_steps(integrator, deprecated)
    sampling, integrator = loop_settings("tune", sampling, integrator, deprecated)
    noise = sensor_noise(sensors, sensor_key, "tune")
    if not isinstance(steps, int) or steps < 1:
        raise ValueError(f"tune: `steps` must be a positive integer, got {steps!r}.")
    if isinstance(patience, bool) or not isinstance(patience, int) or patience < 1:
        raise ValueError(
            f"tune: `patience` must be a positive integer, got {patience!r}."
        )
    if not isinstance(check_every, int) or check_every < 1:
        raise ValueError(
            f"tune: `check_every` must be a positive integer, got {check_every!r}."
        )
    temperatures = _schedule(temperature, controller, steps)
    rates = _geometric(learning_rate, steps, "learning_rate")
    if not np.all(rates > 0):
        raise ValueError(f"tune: `learning_rate` must be > 0, got {learning_rate}.")
    relaxed = temperatures is not None
    runs, setup, hard, u, batch = prepare(
        "tune",
        system,
        controller,
        roads,
        samples,
        parameters,
        log_space,
        bounds,
        objective,
        duration,
        sampling,
        integrator,
        worst_share,
        chosen=chosen,
        noise=noise,
    )
    report = printer(progress, "tune step")

    best_u, best_loss, best_step = u, np.inf, 0
    # The relaxed loss's own progress: while it still falls, the descent is going
    # somewhere even if no hard check has improved lately (the hard loss is jagged at
    # a step's scale; a benchmark run stopped at step 13 of a descent that went on to
    # a 4 % lower loss).
    best_relaxed, relaxed_step = np.inf, 0
    initial, history, simulations = None, [], 0
    checked_u = None

    def judge(u, value, step):
        nonlocal best_u, best_loss, best_step, initial
        value = float(value)
        initial = value if initial is None else initial
        if np.isfinite(value) and value < best_loss:
            best_u, best_loss, best_step = u, value, step

    def check(u, step):
        nonlocal simulations, checked_u
        judge(u, to_host(losses(u, hard, samples, batch, setup, noise)[1]), step)
        simulations += runs
        checked_u = u

    def training_noise(k):
        # Fresh noise at every step for the gradient; the hard law is judged on the
        # fixed draw (`check`). A law judged at every step (no relaxation) is judged
        # on the gradient's own loss: that draw too, for paired comparisons.
        if not isinstance(noise, tuple) or not relaxed:  # no sensors' noise
            return noise
        sensors, key = noise
        return sensors, jax.random.fold_in(jax.random.split(key)[1], k)

    # The parameters placed where every step's update leaves them (replicated over
    # the devices the roads are spread over): one compiled program for every step.
    u = replicate(u, batch_mesh())
    m = tuple(jnp.zeros_like(v) for v in u)
    s = tuple(jnp.zeros_like(v) for v in u)
    start = time.perf_counter()
    reason = f"reached steps = {steps}"
    try:
        for k in range(steps):
            if relaxed and k % check_every == 0:
                check(u, k)
            pair = (
                (system, set_temperature(controller, temperatures[k]))
                if relaxed
                else hard
            )
            value, grads, _ = loss_and_grad(
                u, pair, samples, batch, setup, training_noise(k)
            )
            value = to_host(value)
            simulations += runs
            if not relaxed:
                judge(u, value, k)
            elif np.isfinite(value) and value < best_relaxed:
                best_relaxed, relaxed_step = float(value), k
            history.append(best_loss)
            report(k + 1, best_loss)
            if k - max(best_step, relaxed_step) >= patience:
                reason = f"stalled: no improvement in {patience} steps"
                break
            # The rate and step as arrays: one program for every step.
            u, m, s = _adam(u, m, s, grads, jnp.asarray(rates[k]), jnp.asarray(k + 1.0))
        if relaxed and checked_u is not u and not reason.startswith("stalled"):
            before = best_loss
            check(u, steps)
            history[-1] = best_loss
            if best_loss < before:  # the last line said the loss before this check
                report(len(history), best_loss)
        if best_step == 0 and len(history) > 1:
            reason += (
                "; no step improved on the start, which is kept: try a smaller "
                "`learning_rate`"
            )
    except KeyboardInterrupt:
        reason = f"interrupted at step {len(history) + 1}; the best parameters are kept"
    return tune_result(
        setup,
        hard,
        best_u,
        loss=best_loss,
        initial=initial if initial is not None else np.nan,
        history=history,
        samples=samples,
        validation=validation,
        noise=noise,
        simulations=simulations,
        start=start,
        reason=reason,
        who="tune",
        chosen=chosen,
    )
