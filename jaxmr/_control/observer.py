r"""An observer of the damper's hidden state: the controller's own nominal damper
model, integrated from the measured deflection and the estimated deflection rate,
corrected by the measured force where a load cell exists."""

import equinox as eqx
import jax
import jax.numpy as jnp

from .._custom_types import Array, Bool, Float, Scalar, State
from .._damper import Damper, as_damper
from .._misc import as_float_array, check_concrete, rk4_stages
from .base import DamperPlant


class ObserverState(eqx.Module):
    """A `DamperObserver`'s memory between samples: `started` (False before the first
    sample), `damper` (the nominal damper's state estimate: its hysteresis states,
    then its current dynamics' state), `x` [m or rad] and `v` [m/s or rad/s], the
    deflection and its rate at the last sample, and `commands` [A], the last
    `delay + 1` commands, oldest first (the first is the one acting now)."""

    started: Bool[Array, ""]
    damper: State
    x: Scalar
    v: Scalar
    commands: Float[Array, " delay_plus_one"]


class DamperObserver(eqx.Module):
    r"""The damper's hidden state as a controller can know it: its own nominal model,
    integrated from what it measures.

    Between samples $t_{k-1}$ and $t_k$ the nominal damper's state $\hat s$ (hysteresis
    and current dynamics) is integrated by `substeps` classical RK4 steps
    (`jaxmr`'s one RK4, the simulation's), with the deflection and its rate linear
    between their values at the two samples and the command the damper received over
    the interval (the controller knows its commands and its delay). Where a load cell
    measures the force $F_m$, the hysteresis state is then corrected towards it:
    $$\hat s_h \mathrel{+}= \kappa\,\frac{F_m - \hat F}{\|g\|^2}\,g,\qquad
    g = \partial \hat F/\partial \hat s_h,$$
    so that a fraction $\kappa$ (`gain`) of the force error is removed at each sample
    (the normalised gradient step of a steady-state Kalman filter on a scalar
    output; $\kappa = 0$: no correction). The state is then clipped to the model's
    bounds (`AbstractHysteresis.state_bounds`), so that noise or a mismatched model
    cannot push it where the model cannot go.

    Without a load cell the observer is the model run open-loop on the measured
    motion. That suffices for hysteresis that forgets: a Bouc–Wen state saturates
    within a travel of $z_0$ (1 mm for `passenger_car_mr_damper`), so an error in
    its initial value is gone after that much travel.

    **Arguments:**

    - `model`: the nominal damper (a `Damper` or any jaxmr hysteresis model), e.g.
      the fit of the unit's type; not the simulated device.
    - `gain`: $\kappa \in [0, 1]$ [1], the share of the force error removed per
      sample where the force is measured; default 0.1.
    - `substeps`: RK4 steps per sample (static), default 4 (the simulation's).
    """

    model: Damper = eqx.field(converter=as_damper)
    gain: Float[Array, ""] = eqx.field(converter=as_float_array, default=0.1)
    substeps: int = eqx.field(static=True, default=4)

    def __check_init__(self):
        check_concrete(
            (self.gain >= 0) & (self.gain <= 1),
            f"DamperObserver: `gain` must lie in [0, 1] (the share of the force error "
            f"removed per sample), got {self.gain}.",
            self.gain,
        )
        if isinstance(self.substeps, bool) or not isinstance(self.substeps, int):
            raise TypeError(
                f"DamperObserver: `substeps` must be a whole number, got "
                f"{self.substeps!r}."
            )
        if self.substeps < 1:
            raise ValueError(
                f"DamperObserver: `substeps` must be >= 1, got {self.substeps}."
            )

    def init(self, x: Scalar, v: Scalar, command: Scalar, delay: int) -> ObserverState:
        """The state before the first sample: the model's virgin state at deflection
        `x` and rate `v`, its current dynamics settled at `command` [A], which is
        also every command before the first (as `simulate_system` starts the
        device); `delay` (static) the samples between a command and its action."""
        x, v = jnp.asarray(x), jnp.asarray(v)
        command = jnp.asarray(command, x.dtype)
        return ObserverState(
            jnp.asarray(False),
            self.model.initial_state(x, v, command).astype(x.dtype),
            x,
            v,
            jnp.full((delay + 1,), command),
        )

    def update(
        self,
        state: ObserverState,
        x: Scalar,
        v: Scalar,
        force: Scalar | None,
        dt: float,
    ) -> ObserverState:
        """The state at this sample: integrated from the previous one over `dt` [s]
        (nothing at the first sample), then corrected by the measured `force` [N or
        N·m] (`None`: no load cell), from the deflection `x` [m or rad] and its rate
        `v` [m/s or rad/s] here."""
        model = self.model
        x, v = jnp.asarray(x), jnp.asarray(v)
        applied = state.commands[0]
        h = dt / self.substeps

        def rates(s, motion):
            return model.rates(s, motion[0], motion[1], applied)

        def motion(fraction):
            return (
                state.x + fraction * (x - state.x),
                state.v + fraction * (v - state.v),
            )

        def substep(j, s):
            j = j.astype(x.dtype)
            return rk4_stages(
                rates,
                s,
                h,
                motion(j / self.substeps),
                motion((j + 0.5) / self.substeps),
                motion((j + 1) / self.substeps),
            )

        # A loop rather than unrolled substeps: the same arithmetic, compiled once
        # (unrolled, 4 substeps made tuning's reverse pass take 3x longer to compile).
        s = jax.lax.fori_loop(0, self.substeps, substep, state.damper)
        s = jnp.where(state.started, s, state.damper)
        if force is not None:
            s = self._corrected(s, x, v, jnp.asarray(force), applied)
        s = self._bounded(s, applied)
        return ObserverState(jnp.asarray(True), s, x, v, state.commands)

    def _corrected(self, s, x, v, force, applied):
        k = len(self.model.hysteresis.state_names)
        if k == 0:
            return s

        def predicted(hysteretic):
            return self.model.force(jnp.concatenate([hysteretic, s[k:]]), x, v, applied)

        # Forward mode: the state has a handful of entries, and a reverse pass here
        # would be transposed again by tuning's own reverse pass.
        value, g = predicted(s[:k]), jax.jacfwd(predicted)(s[:k])
        norm = jnp.sum(g**2)
        ok = norm > 0
        step = jnp.where(ok, (force - value) / jnp.where(ok, norm, 1.0), 0.0)
        return s.at[:k].add(self.gain * step * g)

    def _bounded(self, s, applied):
        bounds = self.model.state_bounds(s, applied)
        if bounds is None:
            return s
        return jnp.clip(s, -bounds, bounds)

    def commanded(self, state: ObserverState, command: Scalar) -> ObserverState:
        """The state once the controller has sent `command` [A]."""
        command = jnp.asarray(command, state.commands.dtype)
        commands = jnp.concatenate([state.commands[1:], command[None]])
        return eqx.tree_at(lambda o: o.commands, state, commands)

    def force(self, state: ObserverState) -> Scalar:
        """The nominal model's force [N or N·m] at this sample's state and motion,
        under the command acting now."""
        return self.model.force(state.damper, state.x, state.v, state.commands[0])

    def plant(self, state: ObserverState) -> DamperPlant:
        """The damper as the law's inverse model sees it: the nominal model at the
        observed state, at this sample's deflection and rate."""
        return DamperPlant(self.model, state.damper, state.x, state.v)
