"""Integrators: how `simulate` advances the state. The one place that calls diffrax.

Three modes, chosen by measured accuracy on the published Bouc–Wen brake (γ ≪ β makes
the error of an explicit solver grow ≈ 300× where z crosses zero after a reversal):

- `Adaptive` (default): Dopri8 at rtol 1e-8: torque error ≈ 1e-5 of the peak typically,
  at most 1.3e-4 over the 64 motions (1–5°, 0.5–2 Hz) of benchmarks/simulate_sweep.py
  (rounding decides where z crosses zero); Tsit5/Dopri5 at rtol 1e-6 leave ≈ 1 %.
- `Stiff`: an implicit solver (Kvaerno5 with a Newton root finder: the default chord
  method stalled for n = 2) for stiff settings such as large β, γ at high frequency.
- `FixedStep`: classical RK4 with a fixed number of substeps between output times, run as a
  `lax.scan` (no while loop, no dense output): the fast mode for sweeps and fits. On the
  brake at 1 kHz output: 5e-5 of peak at 1 Hz, ±3.5° with 2 substeps; over 1–5°,
  0.5–2 Hz, 1.5e-3 with 2, 6.6e-4 with 3 and 6.8e-4 with 4 (denser frequency grid).
  Steps too long for the stiffness diverge; that comes back as a result code.
"""

import abc
from collections.abc import Callable

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from ._custom_types import Array, Float, Int
from ._misc import is_concrete, rk4_step
from ._solution import RESULTS


class AbstractIntegrator(eqx.Module):
    """How to integrate $\\dot y = f(t, y, \\mathrm{args})$ and save $y$ at given times."""

    @abc.abstractmethod
    def integrate(
        self,
        vector_field: Callable,
        y0: Array,
        ts: Float[Array, " times"],
        args,
        *,
        jump_ts: Float[Array, " jumps"] | None = None,
    ) -> tuple[Float[Array, "times states"], RESULTS, Int[Array, ""]]:
        """Returns the states at `ts`, a result code and the number of steps taken.

        `jump_ts` [s]: times where the vector field jumps (a current step, the knots of
        a sampled signal), for an adaptive integrator to step to exactly. `simulate`
        passes it only when its signals have such times, so an integrator that ignores
        it may leave it out of its signature.
        """


class AbstractAdaptiveIntegrator(AbstractIntegrator):
    """An adaptive diffrax solve with a PID step-size controller."""

    solver: eqx.AbstractVar[dfx.AbstractAdaptiveSolver]
    rtol: eqx.AbstractVar[float]
    atol: eqx.AbstractVar[float]
    max_steps: eqx.AbstractVar[int]
    adjoint: eqx.AbstractVar[dfx.AbstractAdjoint]

    def __check_init__(self):
        # Here rather than in the solve: rtol = -1 was told it "cannot be met in
        # float64 ... call jax_enable_x64", and max_steps = 0 failed in equinox's
        # checkpointing ("at least one checkpoint").
        name = type(self).__name__
        for field, low in (("rtol", "> 0"), ("atol", ">= 0")):
            value = getattr(self, field)
            if not is_concrete(value):
                continue
            ok = np.ndim(value) == 0 and np.isfinite(value)
            ok = ok and (float(value) > 0 if field == "rtol" else float(value) >= 0)
            if not ok:
                raise ValueError(
                    f"{name}: `{field}` must be a number {low}, got {value!r}."
                )
        if not isinstance(self.max_steps, int) or self.max_steps < 1:
            raise ValueError(
                f"{name}: `max_steps` must be a positive integer, got "
                f"{self.max_steps!r}."
            )

    def integrate(self, vector_field, y0, ts, args, *, jump_ts=None):
        _check_rtol_resolvable(self, ts.dtype)
        controller = dfx.PIDController(rtol=self.rtol, atol=self.atol)
        if jump_ts is not None:
            # Without the jump times the controller finds each jump by rejecting steps
            # until one straddles it within tolerance (measured at rtol 1e-8: ~75 extra
            # steps per current step through a FirstOrderLag; 8x the steps for a linear
            # `Sampled` motion); with them it steps to just before each jump and
            # restarts just after. diffrax 0.7 takes them in ClipStepSizeController
            # (PIDController no longer does).
            controller = dfx.ClipStepSizeController(
                controller, jump_ts=jax.lax.stop_gradient(jump_ts.astype(ts.dtype))
            )
        sol = dfx.diffeqsolve(
            dfx.ODETerm(vector_field),
            self.solver,
            ts[0],
            ts[-1],
            None,
            y0,
            args,
            saveat=dfx.SaveAt(ts=ts),
            stepsize_controller=controller,
            adjoint=self.adjoint,
            max_steps=self.max_steps,
            throw=False,
        )
        result = RESULTS.promote(sol.result)
        if jnp.finfo(ts.dtype).bits < 64:
            # Running out of steps in single precision is nearly always an atol (or a
            # traced rtol) below what float32 resolves: say so, not "increase max_steps".
            result = RESULTS.where(
                result == RESULTS.max_steps_reached, RESULTS.max_steps_float32, result
            )
        return sol.ys, result, sol.stats["num_steps"]


# rtol must exceed this many machine epsilons: in float32 (eps 1.2e-7) rtol 1e-6 solved
# the 10 s brake run, 1e-7 did not.
_RTOL_EPS = 8


def _check_rtol_resolvable(integrator: AbstractAdaptiveIntegrator, dtype) -> None:
    """Raise at trace time when `rtol` is below what `dtype` resolves.

    In float32 (eps 1.2e-7) Dopri8 at rtol 1e-8 or 1e-7 shrinks its steps until they
    stop changing t and the solve ends at `max_steps` (measured: the SAS brake, 10 s
    at 1 Hz, 1e6 steps; rtol 1e-6 took 6e4). That error says "increase max_steps", the
    wrong cure: say float64 is needed instead.
    """
    rtol = integrator.rtol
    if not jnp.issubdtype(dtype, jnp.floating) or not is_concrete(rtol):
        return
    eps = float(jnp.finfo(dtype).eps)
    if float(rtol) < _RTOL_EPS * eps:
        name = type(integrator).__name__
        raise ValueError(
            f"{name}: rtol = {float(rtol):g} cannot be met in {jnp.dtype(dtype).name} "
            f"(machine epsilon {eps:.1e}): the steps would shrink until `max_steps` "
            "runs out. Simulations need float64: call "
            "jax.config.update('jax_enable_x64', True) at startup, before creating "
            f"arrays. To stay in {jnp.dtype(dtype).name}, pass rtol >= "
            f"{_RTOL_EPS * eps:.0e} and an atol above ~1e-8 of the states' size (e.g. "
            f"{name}(rtol=1e-5, atol=1e-8) for states of order 1), or use FixedStep()."
        )


class Adaptive(AbstractAdaptiveIntegrator):
    """An explicit adaptive Runge–Kutta solve (diffrax), the accurate default.

    Steps exactly to the jump times of the signals (a `Steps` current's switching
    times, the knots of a linear `Sampled` motion) instead of locating each jump by
    rejected steps.

    **Arguments:**

    - `solver`: a diffrax adaptive solver, default `diffrax.Dopri8()`.
    - `rtol`, `atol`: tolerances (default 1e-8, 1e-10: float64 is needed; in float32
      an rtol below 1e-6 is refused with an error, as the solve could not meet it).
    - `max_steps`: the most steps one simulation may take.
    - `adjoint`: diffrax adjoint; `diffrax.RecursiveCheckpointAdjoint()` (default) for
      reverse mode, `diffrax.ForwardMode()` for forward-mode Jacobians.
    """

    solver: dfx.AbstractAdaptiveSolver = dfx.Dopri8()
    rtol: float = 1e-8
    atol: float = 1e-10
    max_steps: int = eqx.field(static=True, default=1_000_000)
    adjoint: dfx.AbstractAdjoint = dfx.RecursiveCheckpointAdjoint()


class Stiff(AbstractAdaptiveIntegrator):
    """An implicit adaptive solve (diffrax Kvaerno5 with a Newton root finder: the
    default chord method stalled for n = 2), for stiff settings. 20–60× slower than
    `Adaptive` where the problem is not stiff.

    **Arguments:** as `Adaptive`; default tolerances rtol 1e-6, atol 1e-9.
    """

    solver: dfx.AbstractAdaptiveSolver = dfx.Kvaerno5(
        root_finder=optx.Newton(rtol=1e-8, atol=1e-10)
    )
    rtol: float = 1e-6
    atol: float = 1e-9
    max_steps: int = eqx.field(static=True, default=1_000_000)
    adjoint: dfx.AbstractAdjoint = dfx.RecursiveCheckpointAdjoint()


class FixedStep(AbstractIntegrator):
    r"""Fixed-step classical RK4 as a `lax.scan`: the fast mode for sweeps and fits.

    Takes `substeps` equal steps between consecutive output times, so the step is
    $(t_{k+1} - t_k)/\text{substeps}$ (0.5 ms for `substeps=2` at 1 kHz output). No
    while loop and no dense output: as fast as a hand-written kernel, differentiable in
    forward and reverse mode. A step too long for the problem's stiffness makes the state
    non-finite, which comes back as `RESULTS.nonfinite`.

    The one step object every entry point takes under `integrator=`: `k` steps per
    output interval here, per sample interval of the data in `fit` (as
    `StepPolicy(substeps=k)`), per controller sample in `simulate_system`.

    **Arguments:**

    - `substeps`: RK4 steps per output interval (static), default 4 (≤ 7e-4 of peak
      torque for the brake under sines up to 5°, 2 Hz at 1 kHz output). A motion
      whose velocity jumps (`Triangle`, a linearly interpolated `Sampled`) costs RK4
      its order at each jump: the error then falls only as the step (the brake under
      a triangle: 0.7 % of peak at `substeps=4`, 0.01 % at 256): use `Adaptive`
      there.
    """

    substeps: int = eqx.field(static=True, default=4)

    def __check_init__(self):
        if not isinstance(self.substeps, int) or self.substeps < 1:
            raise ValueError(
                f"FixedStep: `substeps` must be a positive integer, got {self.substeps}."
            )

    def integrate(self, vector_field, y0, ts, args, *, jump_ts=None):
        # Jump times are ignored: the steps are tied to the output times (put a jump on
        # an output time, or use Adaptive, to resolve it exactly).
        del jump_ts

        def interval(y, t_pair):
            t0, t1 = t_pair
            h = (t1 - t0) / self.substeps

            def step(k, y):
                return rk4_step(vector_field, t0 + k * h, y, h, args)

            # Unrolled (up to 8 steps): a loop inside the scan's loop costs more per
            # iteration than a step of a small model (the brake sweep's 64 motions
            # ran ~25 % faster with substeps=3 unrolled; unrolling the outer scan
            # as well was slower and compiled 2-4x longer).
            y = jax.lax.fori_loop(
                0, self.substeps, step, y, unroll=min(self.substeps, 8)
            )
            return y, y

        _, ys = jax.lax.scan(interval, y0, (ts[:-1], ts[1:]))
        ys = jnp.concatenate([y0[None], ys])
        finite = jnp.all(jnp.isfinite(ys))
        # jaxmr's RESULTS extends diffrax's, whose codes pyright types as diffrax's enum.
        result = RESULTS.where(finite, RESULTS.successful, RESULTS.nonfinite)  # pyright: ignore[reportArgumentType]
        num_steps = jnp.asarray((ts.shape[0] - 1) * self.substeps)
        return ys, result, num_steps
