"""Every model, generically: jit equals no-jit, vmap over parameters, JVP and gradients
against finite differences, finite gradients at a z = 0 start and velocity reversals.

Fixed-step RK4 is used where derivatives are compared with finite differences: it makes
the simulated force a smooth function of the parameters, so a central difference is
accurate to O(eps²) and a tight tolerance can be stated. The adaptive integrator is
checked separately (its step-size selection adds noise to finite differences).
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmr
from jaxmr._damper import as_damper
from jaxmr._signal import as_signal
from jaxmr._simulate import _run

from .helpers import MODEL_CASES, finite_difference_jvp, relative_tangent

CASES = pytest.mark.parametrize("case", MODEL_CASES, ids=repr)


def _setup(case):
    """The case with its fixed RK4 steps (`case.substeps` per interval of
    `case.ts()`), where there are more than two taken one per output sample: the same
    steps on a grid refined by that factor. XLA unrolls a `FixedStep`'s substeps (up
    to 8) in the compiled loop, and compiling their reverse pass dominated this file
    (BWBN's 10 substeps: 69 s, one step on the refined grid: 9 s). The cases of two
    substeps keep them: the derivatives through the substep loop stay checked."""
    device = case.device()
    motion, current, ts = case.motion(), case.current(), case.ts()
    if case.substeps <= 2:
        return device, motion, current, ts, jaxmr.FixedStep(substeps=case.substeps)
    ts = jnp.linspace(ts[0], ts[-1], (ts.shape[0] - 1) * case.substeps + 1)
    return device, motion, current, ts, jaxmr.FixedStep(substeps=1)


def _loss_fn(case):
    """A scalar that depends on the whole force history: mean squared force against a
    fixed weighting, so that every sample's derivative counts."""
    _, motion, current, ts, integrator = _setup(case)

    @eqx.filter_jit
    def force(device):
        return jaxmr.simulate(device, motion, current, ts, integrator=integrator).force

    def loss(device):
        f = force(device)
        weights = jnp.cos(jnp.linspace(0.0, 3.0, f.shape[0]))
        return jnp.mean(weights * f) + 1e-3 * jnp.mean(f**2)

    return force, loss


@CASES
def test_jit_equals_no_jit(case):
    device, motion, current, ts, integrator = _setup(case)
    jitted = jaxmr.simulate(device, motion, current, ts, integrator=integrator)
    # Without the outer jit (the integrator's scan still compiles its own body).
    outer_eager = _run(
        as_damper(device), motion, as_signal(current), ts, integrator, None
    )
    # Same operations in the same order: agreement to rounding (XLA may fuse
    # differently, and reassociation costs a few ulps per step).
    np.testing.assert_allclose(jitted.force, outer_eager.force, rtol=1e-9, atol=1e-12)
    # Fully eager (op by op, slow): a few steps from t = 0.1 s, where v != 0.
    short, one_step = jnp.linspace(0.1, 0.1002, 3), jaxmr.FixedStep(substeps=1)
    jitted = jaxmr.simulate(device, motion, current, short, integrator=one_step)
    with jax.disable_jit():
        eager = jaxmr.simulate(device, motion, current, short, integrator=one_step)
    np.testing.assert_allclose(jitted.force, eager.force, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(jitted.states, eager.states, rtol=1e-10, atol=1e-14)


@CASES
def test_vmap_over_parameters(case):
    device, motion, current, ts, integrator = _setup(case)
    arrays, static = eqx.partition(device, eqx.is_array)
    scales = jnp.array([0.98, 1.0, 1.02])  # small: keeps every model physical
    batch = jax.vmap(lambda s: jax.tree.map(lambda a: a * s, arrays))(scales)

    def run(params):
        d = eqx.combine(params, static)
        return jaxmr.simulate(d, motion, current, ts, integrator=integrator).force

    batched = eqx.filter_jit(jax.vmap(run))(batch)
    for k, s in enumerate(scales):
        single = run(jax.tree.map(lambda a, s=s: a * s, arrays))
        # vmap changes nothing but the batching: agreement to rounding.
        np.testing.assert_allclose(batched[k], single, rtol=1e-9, atol=1e-12)


@CASES
def test_jvp_and_grad_against_finite_differences(case):
    device = case.device()
    _, loss = _loss_fn(case)
    arrays, static = eqx.partition(device, eqx.is_array)
    tangent = relative_tangent(arrays)

    def loss_of(params):
        return loss(eqx.combine(params, static))

    @eqx.filter_jit
    def derivatives(params, tangent):
        # One compilation for the value, both modes and the finite difference.
        value, jvp = jax.jvp(loss_of, (params,), (tangent,))
        grads = jax.grad(loss_of)(params)
        fd = finite_difference_jvp(loss_of, params, tangent, eps=1e-6)
        return value, jvp, grads, fd

    value, jvp, grads, fd = derivatives(arrays, tangent)
    grad_dot = sum(
        jnp.vdot(g, t)
        for g, t in zip(jax.tree.leaves(grads), jax.tree.leaves(tangent), strict=True)
    )
    assert np.isfinite(value) and np.isfinite(jvp) and np.isfinite(grad_dot)
    assert all(np.all(np.isfinite(g)) for g in jax.tree.leaves(grads))
    # Forward and reverse mode differentiate the same program: agreement to rounding.
    np.testing.assert_allclose(grad_dot, jvp, rtol=1e-8, atol=1e-12)
    # Central difference with relative step 1e-6: truncation O(1e-12) relative, rounding
    # O(1e-16/1e-6) = 1e-10 relative to the loss; 1e-5 leaves a wide margin.
    scale = max(abs(float(jvp)), abs(float(value)), 1e-12)
    assert abs(float(jvp) - float(fd)) <= 1e-5 * scale, (jvp, fd)


# The adaptive solve's gradient is diffrax's; what the model adds is checked above. Here:
# the settings users reach with the default integrator — a z = 0 start with n < 1, a stiff
# model, and a discontinuous current through a lag.
ADAPTIVE_CASES = [
    c
    for c in MODEL_CASES
    if c.name
    in ("bouc_wen_sas_brake", "spencer_1997", "bouc_wen_with_lag_and_current_steps")
]


@pytest.mark.parametrize("case", ADAPTIVE_CASES, ids=repr)
def test_gradient_with_adaptive_solver(case):
    """Reverse mode through diffrax's adaptive solve: finite (z = 0 start, n < 1,
    reversals) and equal to a finite difference of a tighter solve.

    Not compared with the fixed-step gradient: with n < 1 the sensitivity equation is
    singular where z crosses zero, and RK4 at h = 0.5 ms misses d/dγ of the SAS brake by
    16 % (h = 0.05 ms: 0.7 %), while the adaptive gradient is stable to 1e-6 between
    rtol 1e-9 and 1e-12.
    """
    device, motion, current, ts = (
        case.device(),
        case.motion(),
        case.current(),
        case.ts(),
    )
    arrays, static = eqx.partition(device, eqx.is_array)
    tangent = relative_tangent(arrays, seed=1)

    def loss(params, integrator):
        f = jaxmr.simulate(
            eqx.combine(params, static), motion, current, ts, integrator=integrator
        ).force
        return jnp.mean(f**2)

    @eqx.filter_jit
    def derivatives(params, tangent):
        grads = jax.grad(loss)(params, jaxmr.Adaptive(rtol=1e-10, atol=1e-13))
        tight = jaxmr.Adaptive(rtol=1e-12, atol=1e-15)
        fd = finite_difference_jvp(lambda p: loss(p, tight), params, tangent, eps=1e-5)
        return grads, fd

    grads, fd = derivatives(arrays, tangent)
    leaves = jax.tree.leaves(grads)
    assert all(np.all(np.isfinite(g)) for g in leaves)
    grad_dot = sum(
        jnp.vdot(g, t) for g, t in zip(leaves, jax.tree.leaves(tangent), strict=True)
    )
    # Solver noise ~1e-12 over a step of 1e-5 gives ~1e-7 in the difference; truncation
    # ~1e-10. The adaptive gradient's own error is ~rtol. 1e-4 relative is a safe bound.
    assert abs(float(grad_dot) - float(fd)) <= 1e-4 * abs(float(fd)), (grad_dot, fd)
