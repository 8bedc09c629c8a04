"""The solver loop: Levenberg–Marquardt (optimistix), stepped from Python through
optimistix's public `init`/`step`/`terminate`, so that a fit can show progress, stop on
stalled progress (solver noise can keep the optimiser's own convergence test from ever
firing), and keep the best parameters when it fails or is interrupted.

The residual function carries its own materialised Jacobian (one forward-mode pass,
`residual.value_and_jacobian`); starts are spread in value space; the variables are
scaled once by their Jacobian columns (Moré's scaling, frozen at the start).
"""

import functools
import time
from collections.abc import Callable
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jax.flatten_util import ravel_pytree
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from .._custom_types import Array, Bool, Float
from .._distribute import BATCH as MESH_AXIS, batch_mesh, replicate, to_host
from .._misc import to_device
from .._parameter import Bounded, Fixed, Positive, free_filter, is_parameter
from .._traced import cached
from .residual import traced_once, value_and_jacobian, value_and_jacobian_jit
from .result import Outcome, StopReason


class _LMState(eqx.Module):
    first_step: Bool[Array, ""]
    y_eval: Array  # the trial point (flat)
    radius: Float[Array, ""]  # the trust region as a step size: λ = 1/radius
    residual: Array  # at the last accepted point
    gram: Array  # JᵀJ there, (variables, variables)
    gradient: Array  # Jᵀr there, (variables,)
    # The loss reduction the Gauss–Newton model promises there (`_damped_step`).
    available: Float[Array, ""]
    aux: Any
    terminate: Bool[Array, ""]
    result: optx.RESULTS


class FastLevenbergMarquardt(optx.AbstractLeastSquaresSolver):
    r"""Levenberg–Marquardt with each trial point's residual and Jacobian from one
    forward-mode pass, and a bold trust region.

    optimistix's `LevenbergMarquardt` linearises the residual through lineax, which
    materialises the linearisation column by column (measured 10x slower than one
    `jax.jacfwd`). Here a trial point's residual and Jacobian come from one
    forward-mode pass (`jax.jacfwd`, all columns at once, the residual its primal):
    the residual decides whether the step is accepted, and the Jacobian is kept where
    it is. Evaluating the residual first and the Jacobian only at accepted points
    simulated every accepted point twice and compiled a second simulation loop into
    the step; with this trust region few points are rejected (the 30-record UTFSM
    fit: 4 of 27), and one pass made that fit 1.4 s faster (0.9 s of it compiling)
    and the Bouc–Wen benchmark's reach its target 0.5 s sooner. The step and the
    trust-region rule are optimistix's (`DampedNewtonDescent`,
    `ClassicalTrustRegion`): the damped Gauss–Newton step
    $(J^\top J + \lambda I)\,\delta = J^\top r$, λ = 1/radius, the least-squares
    solution of $[J; \sqrt{\lambda} I]\,\delta = [r; 0]$; a step is accepted when it
    achieves 1 % of the predicted reduction, and the radius grows 10x (optimistix:
    3.5x) after one that achieves 75 % (optimistix: 99 %) and shrinks 4x after a
    rejection. From starts far from the optimum (the published UTFSM model, a
    12-parameter Spencer fit) optimistix's constants crept for 30+ steps before the
    damping had relaxed: 47 instead of 80+ steps to the same optimum.

    The step is solved from $J^\top J$ and $J^\top r$ (p × p and p, formed by XLA
    where the Jacobian is), through the eigendecomposition of $J^\top J$, with λ at
    least `MIN_DAMPING` × its largest eigenvalue (below that the normal equations'
    rounding, ~1e-16 of it, would decide the step). A QR factorisation of the tall
    $[J; \sqrt{\lambda} I]$ (optimistix's, lineax's) is a LAPACK call on the whole
    Jacobian inside the program that simulates: on a CPU, OpenBLAS's worker threads,
    which spin for a while after each call, then competed with XLA's for the cores, and
    a step of the Bouc–Wen benchmark (6 parameters, 8192 residuals, 2 cores) took
    3x its residual and Jacobian (0.14 s against 0.045 s). The state then holds no
    n × p Jacobian either.

    A trial point is rejected (the region shrinks 4x) where its loss is not finite,
    and where its Jacobian is not finite or has blown up: JᵀJ's largest diagonal
    above 1/`MIN_DAMPING`, on columns of unit norm at the start. There fixed-step
    RK4 has passed its stability limit while the simulation is still finite, and
    the next step would be nan or, under the least damping, frozen.

    **Arguments:** `rtol`, `atol`: optimistix's Cauchy convergence test (an accepted
    step that changes every variable by less than `atol + rtol·|y|` and every residual
    by less than `atol + rtol·|r|`); `initial_radius`: the first damped step's trust
    region (λ = 1/`initial_radius`, on variables whose Jacobian columns `jaxmr.fit`
    scales to unit norm).
    """

    rtol: float = 1e-8
    atol: float = 1e-10
    norm: Callable = optx.max_norm
    initial_radius: float = 1.0

    def __check_init__(self):
        if not (
            isinstance(self.initial_radius, (int, float)) and self.initial_radius > 0
        ):
            raise ValueError(
                "FastLevenbergMarquardt: `initial_radius` must be a positive number, "
                f"got {self.initial_radius!r}."
            )

    def init(self, fn, y, args, options, f_struct, aux_struct, tags):
        flat, _ = ravel_pytree(y)
        # No point accepted yet: the aux (`_lm_fn`'s loss and point) is +inf, not 0,
        # so that a start whose loss is not finite does not read as a loss of 0 at
        # the origin (the aux `step` returns until it accepts one).
        unset = lambda s: jnp.full(
            s.shape, jnp.inf if jnp.issubdtype(s.dtype, jnp.inexact) else 0, s.dtype
        )
        residual = jnp.zeros(_size(f_struct), flat.dtype)
        return _LMState(
            first_step=jnp.array(True),
            y_eval=flat,
            radius=jnp.array(self.initial_radius, flat.dtype),
            residual=residual,
            gram=jnp.zeros((flat.size, flat.size), flat.dtype),
            gradient=jnp.zeros(flat.size, flat.dtype),
            available=jnp.array(jnp.inf, flat.dtype),
            aux=jax.tree.map(unset, aux_struct),
            terminate=jnp.array(False),
            result=optx.RESULTS.successful,
        )

    def step(self, fn, y, args, options, state, tags):
        flat, unravel = ravel_pytree(y)

        def residual_fn(x):
            r, aux = fn(unravel(x), args)
            return ravel_pytree(r)[0], aux

        # The trial point's residual and Jacobian in one forward-mode pass (the
        # residual is its primal): the residual decides, the Jacobian is kept where
        # the step is accepted.
        def evaluate(x):
            def both(x):
                r, aux = residual_fn(x)
                return r, (r, aux)

            jacobian, (r, aux) = jax.jacfwd(both, has_aux=True)(x)
            return r, aux, jacobian.T @ jacobian, jacobian.T @ r

        r_eval, aux_eval, gram, gradient = evaluate(state.y_eval)
        loss, loss_eval = _half_sum_squares(state.residual), _half_sum_squares(r_eval)
        # optimistix's ClassicalTrustRegion: the linear model's predicted change,
        # ½‖J d + r‖² − ½‖r‖² = ½ dᵀ(JᵀJ)d + dᵀ(Jᵀr).
        diff = state.y_eval - flat
        predicted = 0.5 * diff @ (state.gram @ diff) + diff @ state.gradient
        change = loss_eval - loss
        accept = state.first_step | (change <= 0.01 * predicted)
        good = (change < 0.75 * predicted) & (predicted < 0) & ~state.first_step
        radius = state.radius * jnp.where(accept, jnp.where(good, 10.0, 1.0), 0.25)
        radius = jnp.where(jnp.isfinite(loss_eval), radius, state.radius * 0.25)
        accept = accept & jnp.isfinite(loss_eval)
        # A point whose residual is finite but whose linearisation is not, or has
        # blown up (a column norm grown a millionfold from the start's scaled unit
        # norm: JᵀJ's largest diagonal above 1/MIN_DAMPING, where the least damping
        # freezes every direction of the start's scale), is rejected like one whose
        # loss is not finite: the fit goes on from the last point with a sound
        # linearisation, in a smaller region. Fixed-step RK4 past its stability
        # limit gives such points: a Bouc–Wen screening fit on 18 UTFSM files
        # stepped to n = 12-17, its simulation still finite and the sensitivities
        # to n, β and γ ~1e88 (JᵀJ ~1e181); it stopped there, "failed" or
        # "converged". The start (the first step) is exempt: its columns are
        # unscaled where the column scale is measured.
        linearised = (
            jnp.all(jnp.isfinite(gram))
            & jnp.all(jnp.isfinite(gradient))
            & (state.first_step | (jnp.max(jnp.diagonal(gram)) <= 1 / MIN_DAMPING))
        )
        radius = jnp.where(accept & ~linearised, state.radius * 0.25, radius)
        accept = accept & linearised
        new_y = jnp.where(accept, state.y_eval, flat)
        residual = jnp.where(accept, r_eval, state.residual)
        gram = jnp.where(accept, gram, state.gram)
        gradient = jnp.where(accept, gradient, state.gradient)
        aux = jax.tree.map(lambda a, b: jnp.where(accept, a, b), aux_eval, state.aux)
        # optimistix's Cauchy test, on accepted steps.
        y_scale = self.atol + self.rtol * jnp.abs(state.y_eval)
        f_scale = self.atol + self.rtol * jnp.abs(r_eval)
        terminate = (
            accept
            & ~state.first_step
            & (self.norm(jnp.abs(diff) / y_scale) < 1)
            & (self.norm(jnp.abs(r_eval - state.residual) / f_scale) < 1)
        )
        # The damped Gauss–Newton step from the new point (optimistix's
        # `damped_newton_step`), from the p × p normal equations (see the class's
        # docstring), written with jax.numpy: inside `shard_map` (`fit_each`'s
        # chunks) lineax refused the vector, whose structure carries the mesh's
        # sharding and the operator's not. The eigendecomposition takes one member
        # at a time (see `_one_matrix_at_a_time`).
        y_eval, available, result = _next_trial(new_y, gram, gradient, radius)
        state = _LMState(
            first_step=jnp.array(False),
            y_eval=y_eval,
            radius=radius,
            residual=residual,
            gram=gram,
            gradient=gradient,
            available=available,
            aux=aux,
            terminate=terminate,
            result=result,
        )
        return unravel(new_y), state, aux

    def terminate(self, fn, y, args, options, state, tags):
        return state.terminate, state.result

    def postprocess(self, fn, y, aux, args, options, state, tags, result):
        return y, aux, {}


def _one_matrix_at_a_time(fn):
    """`fn`, whose LAPACK calls (jaxlib's CPU factorisations and solves) are made one
    matrix at a time when it is batched (`jax.vmap`: the starts of `fit`, the
    problems of `fit_each`), in a loop (`jax.custom_batching.sequential_vmap`).

    A batched call whose work exceeds 2e5 flop is split by jaxlib over XLA's CPU
    thread pool (its `ParallelBatchMap`), and the pool thread that makes the call
    blocks until the pieces are done. With several host devices
    (`--xla_force_host_platform_device_count`, as `jaxmr fit` sets) every device's
    program runs on that same pool: when each pool thread was such a waiter, none
    was left to run the pieces and the fit hung with the CPU idle (two starts of a
    Spencer fit on two UTFSM files, 2 devices on 2 cores; `fit_each` over 2 host
    devices). One matrix is factored on the calling thread. Each matrix gets the
    same LAPACK routine as in the batched call: the results are the same bits.
    """
    return jax.custom_batching.sequential_vmap(fn)


def column_mesh(solver, free, data) -> Mesh | None:
    """The devices a fit from one start with `solver` splits its Jacobian's columns
    over (`residual.value_and_jacobian`): every device of this process (a CPU's
    cores, as `jaxmr.devices.configure_cpu` makes them), where there are several, the
    solver is a `FastLevenbergMarquardt`, the fit runs in one process, it has at
    least as many free variables, and its `data` (None where the residual closes
    over them, as `fit_system`'s does) are not already spread over the devices by
    lanes (`placed_like_data`); else None."""
    mesh = batch_mesh(local=True)
    size = sum(np.size(a) for a in jax.tree.leaves(free))
    lanes = getattr(getattr(data, "step", None), "sharding", None)
    if (
        not isinstance(solver, FastLevenbergMarquardt)
        or isinstance(lanes, NamedSharding)
        or jax.process_count() > 1
        or mesh is None
        or size < mesh.size
    ):
        return None
    return mesh


def _next_trial(y, gram, gradient, radius):
    """The trial point after `y` (flat): `y` minus the damped Gauss–Newton step
    (`_damped_step`, λ = 1/`radius`); the loss reduction the model promises there;
    and whether the step is finite (optimistix's `RESULTS`)."""
    step, available = _damped_step(gram, gradient, 1.0 / radius)
    result = optx.RESULTS.where(
        jnp.all(jnp.isfinite(step)), optx.RESULTS.successful, optx.RESULTS.nonfinite
    )
    return y - step, available, result


# The least damping λ, relative to the largest eigenvalue of JᵀJ: the eigenvalues are
# known to ~1e-16 of it, so a smaller λ would let rounding decide the step along
# directions the data barely see (their relative accuracy is then still ~1e-4).
MIN_DAMPING = 1e-12


def _damped_step_in(xp, gram, gradient, lam):
    r"""$\delta = (J^\top J + \lambda I)^{-1} J^\top r$ from `gram` $= J^\top J$ and
    `gradient` $= J^\top r$, λ at least `MIN_DAMPING` × the largest eigenvalue; and
    the loss reduction the undamped Gauss–Newton step promises,
    $\tfrac12 g^\top (J^\top J)^{-1} g$ (with the same least damping).
    `xp`: the array namespace, `jax.numpy` (`_damped_step`) or NumPy (on the host,
    `_rescaled_first_step`)."""
    w, v = xp.linalg.eigh(gram)
    w = xp.maximum(w, 0.0)  # JᵀJ is positive semi-definite; rounding is not
    floor = xp.maximum(MIN_DAMPING * w[-1], xp.finfo(w.dtype).tiny)
    projected = v.T @ gradient
    available = 0.5 * xp.sum(projected**2 / (w + floor))
    return v @ (projected / (w + xp.maximum(lam, floor))), available


_damped_step = _one_matrix_at_a_time(functools.partial(_damped_step_in, jnp))


def _size(struct) -> int:
    return int(sum(np.prod(s.shape, dtype=int) for s in jax.tree.leaves(struct)))


def _half_sum_squares(r):
    return 0.5 * jnp.sum(r**2)


# ---------------------------------------------------------------------------------------
# Column scaling


def column_scale(residuals_fn, free, static, data, extra):
    """Per free variable, 1/(norm of its Jacobian column) at the start.

    optimistix's Levenberg–Marquardt damps with λ·I, which suits unit-norm columns;
    a model's sensitivities span decades (log C0a against log α for the brake), and
    unscaled it crept along the valley for ~3x more steps. One start of a
    `FastLevenbergMarquardt` fit reads them from its own first step instead
    (`scale_and_first_step`).
    """
    _, jac = value_and_jacobian_jit(residuals_fn, free, static, data, extra)
    # On the device (the Jacobian can be large), only the p norms brought back.
    return _scale_from_norms(jax.tree.map(to_host, _column_norms(jac)), data)


def column_scales(residuals_fn, ys, static, data, chunk, mesh):
    """`column_scale` of each member of a batch of independent problems (axis 0 of
    `ys` and `data`, as `iterate` with `data_axis` 0, `chunk` and `mesh` runs them),
    on the host: each problem is scaled by its own Jacobian at its own start, as
    `fit` alone would scale it. (One scale for all, the first problem's, stalled a
    problem whose force was 1000x the first's at NRMSE 0.25, against 0.020 alone.)
    Computed in `iterate`'s chunks, so that each member's scale is the same bits in
    every layout."""
    norms = _batched_column_norms(ys, (residuals_fn, static, data, None), chunk, mesh)
    norms = jax.tree.map(to_host, norms)
    leaves = jax.tree.leaves(norms)
    count = leaves[0].shape[0]
    largest = np.max(
        np.stack([np.max(n.reshape(count, -1), axis=1) for n in leaves]), axis=0
    )
    floor = np.maximum(NORM_FLOOR * largest, 1e-300)  # per member, as `_norm_floor`

    def scale(n):
        f = floor.reshape((count,) + (1,) * (n.ndim - 1))
        return 1.0 / np.maximum(n, f)

    return jax.tree.map(scale, norms)


# Kept on disk as the step is (`cached`): a second `fit_each` of the same shapes
# compiles neither.
@cached(lambda ys, *_: ys)
def _batched_column_norms(ys, args, chunk, mesh):
    def one(y, args):
        fn, static, data, extra = args
        _, jac = value_and_jacobian(fn, y, static, data, extra)
        return _column_norms(jac)

    return _over_batch(one, (ys,), args, 0, chunk, mesh)


def _scale_from_norms(norms, data):
    # The rest in NumPy on the host (p numbers): as eager `jnp` operations each
    # compiled once per shape, a few hundred ms of a first fit. Placed as
    # `scale_and_first_step` placed its unit scale, so that `iterate`'s steps, whose
    # parameters are divided by this scale, reuse that step's program.
    floor = _norm_floor(norms)
    return placed_like_data(
        jax.tree.map(lambda n: to_device(1.0 / np.maximum(n, floor)), norms), data
    )


class FirstStep(NamedTuple):
    """`iterate`'s first step, made before it: the solver state's static part and
    the step's outputs (`_step`'s: points, state arrays, losses, points they belong
    to, flags)."""

    static_state: Any
    outputs: tuple


def scale_and_first_step(
    solver, residuals_fn, scaled_residuals, free, static, data, columns=None
):
    """The column scale (`column_scale`) of one start `free`, and, for a
    `FastLevenbergMarquardt`, `iterate`'s first step from it in the scaled
    variables (a `FirstStep`; None for other solvers), for `iterate` stepping that
    start with `solver` on `(scaled_residuals, static, data, scale)`.

    The solver's own first step at the start with unit scale gives JᵀJ and Jᵀr there:
    the column norms are read from JᵀJ's diagonal, and the same step in the scaled
    variables y/s is that one with JᵀJ → D JᵀJ D, Jᵀr → D Jᵀr (D = diag(s)) and its
    damped step solved anew. So the fit compiles its Jacobian once, in the step it
    then reuses (the 14-parameter UTFSM fit: a third of its compilation, when the
    norms came from a Jacobian program of their own), and evaluates it at the start
    once (its first step had evaluated it again: on the Bouc–Wen benchmark 0.15 s
    of 3.2 s).
    """
    if not isinstance(solver, FastLevenbergMarquardt):
        return column_scale(residuals_fn, free, static, data, None), None
    # Every array the step is given placed alike (`placed_like_data`; or whole on
    # every device its columns are split over), so that it compiles once.
    if columns is None:
        place = lambda tree: placed_like_data(jax.tree.map(to_device, tree), data)
    else:
        place = lambda tree: replicate(jax.tree.map(to_device, tree), columns)
    unit = place(jax.tree.map(lambda a: np.ones(np.shape(a), a.dtype), free))
    # On the host: `one_start` would compile a program to divide by ones.
    ys = place(jax.tree.map(lambda a: to_host(a)[None], free))
    args = (scaled_residuals, static, data, unit)
    dynamic, static_state = eqx.partition(
        _init(solver, ys, args, None, None, None), eqx.is_array
    )
    # `columns` passed by position: `cached` keeps only calls without keywords.
    outputs = _step(solver, ys, dynamic, static_state, args, None, None, None, columns)
    # The first step accepts the start: its JᵀJ is the start's, columns unscaled.
    # Unravelled in NumPy, like `free`'s leaves (their order and shapes).
    norms = np.sqrt(np.diagonal(to_host(outputs[1].gram)[0]))
    leaves, treedef = jax.tree.flatten(free)
    sizes = np.cumsum([np.size(a) for a in leaves])[:-1]
    parts = np.split(norms, sizes)
    norms = jax.tree.unflatten(
        treedef, [p.reshape(np.shape(a)) for p, a in zip(parts, leaves, strict=True)]
    )
    scale = _scale_from_norms(norms, data)
    if columns is not None:
        scale = place(scale)
    return scale, FirstStep(
        static_state, _rescaled_first_step(solver, outputs, static_state, scale, place)
    )


def _rescaled_first_step(solver, outputs, static_state, scale, place):
    """A `FastLevenbergMarquardt`'s first step from one start (a batch of one), made
    with unit scale, as made in the variables divided by `scale`: the same accepted
    point, loss and radius; JᵀJ and Jᵀr in the new columns; the next trial point
    from the damped step solved there; the solver's verdict on that state.

    On the host, in NumPy (p numbers and a p × p eigendecomposition): as a jitted
    program of its own it compiled for 0.1 s of every cold single-start fit (the
    Bouc–Wen benchmark's 2.3 s to its target) to do microseconds of work. Its
    arrays go back placed as the step's inputs were (`place`), so that the next
    step reuses its program."""
    ys, dynamic, loss, at, _, _ = outputs
    state = eqx.combine(dynamic, static_state)
    s = np.concatenate([np.ravel(to_host(a)) for a in jax.tree.leaves(scale)])
    gram = to_host(state.gram)[0] * s[:, None] * s[None, :]
    gradient = to_host(state.gradient)[0] * s
    y = np.concatenate([np.ravel(to_host(a)[0]) for a in jax.tree.leaves(ys)])
    radius = to_host(state.radius)[0]
    step, available = _damped_step_in(np, gram, gradient, 1.0 / radius)
    finite = bool(np.all(np.isfinite(step)))
    result = jax.tree.map(
        lambda ok, bad: np.asarray(ok if finite else bad)[None],
        optx.RESULTS.successful,
        optx.RESULTS.nonfinite,
    )
    host_scale = jax.tree.map(to_host, scale)
    divided = lambda tree: jax.tree.map(lambda a, c: to_host(a) / c, tree, host_scale)
    # `tree_at`, not `dataclasses.replace`: the state's fields are batched here.
    state = eqx.tree_at(
        lambda st: (
            st.y_eval,
            st.gram,
            st.gradient,
            st.available,
            st.aux[1],
            st.result,
        ),
        state,
        place(
            (
                (y / s - step)[None],
                gram[None],
                gradient[None],
                np.asarray(available)[None],
                divided(state.aux[1]),
                result,
            )
        ),
    )
    done, verdict = solver.terminate(_lm_fn, None, None, _OPTIONS, state, frozenset())
    # Compared on the host: `!=` of two `RESULTS` compiles an eager program.
    code = lambda r: np.reshape(to_host(jax.tree.leaves(r)[0]), (1,))
    return (
        place(divided(ys)),
        eqx.filter(state, eqx.is_array),
        loss,
        place(divided(at)),
        place(np.reshape(to_host(done), (1,))),
        place(code(verdict) != code(optx.RESULTS.successful)),
    )


@eqx.filter_jit
def _column_norms(jac):
    return jax.tree.map(lambda j: jnp.sqrt(jnp.sum(j**2, axis=0)), jac)


# The smallest column norm scaled by, as a share of the largest: a variable the data
# barely see (an effect below the noise) is not magnified more than 100x; unbounded,
# its huge steps sent such a parameter to zero.
NORM_FLOOR = 1e-2


def _norm_floor(norms) -> float:
    """The smallest column norm scaled by (`NORM_FLOOR` of the largest)."""
    largest = max(float(np.max(n)) for n in jax.tree.leaves(norms))
    return max(NORM_FLOOR * largest, 1e-300)


def placed_like_data(tree, data):
    """`tree` replicated over the devices the fit's lanes are spread over
    (`_lanes_on_devices`), or unchanged where they are not. A jitted step is traced
    and compiled again for every new placement of its inputs: the parameters and
    their scale placed alike in every call, the step compiles once."""
    sharding = getattr(getattr(data, "step", None), "sharding", None)
    mesh = sharding.mesh if isinstance(sharding, NamedSharding) else None
    return replicate(tree, mesh) if isinstance(mesh, Mesh) else tree


def unscaled_member(ys, scale, k: int):
    """Member `k` of the batch `ys` (axis 0), multiplied back by the column `scale`:
    one program, where eager indexing compiled a slice per leaf (`k` passed as an
    array, so that another member does not compile it again)."""
    return _unscaled_member(ys, scale, np.asarray(k))


@eqx.filter_jit
def _unscaled_member(ys, scale, k):
    return jax.tree.map(lambda y, s: y[k] * s, ys, scale)


# Jitted: its callers are eager, where each leaf's division compiled apart in a fresh
# process.
@eqx.filter_jit
def divide(ys, scale):
    return jax.tree.map(lambda y, s: y / s, ys, scale)


@eqx.filter_jit
def one_start(free, scale):
    """`free` divided by `scale`, as a batch of one (axis 0)."""
    return jax.tree.map(lambda y, s: (y / s)[None], free, scale)


def multiply(ys, scale):
    return jax.tree.map(lambda y, s: y * s, ys, scale)


# ---------------------------------------------------------------------------------------
# Starts


def spread_starts(constrained, starts: int, spread: float, key, scale):
    """The model's free variables and `starts − 1` random variations of them, stacked
    on axis 0 (the layout of `eqx.filter(constrained, free_filter(constrained))`).

    Each free parameter's *value* is multiplied by a log-uniform factor in
    [1/spread, spread]: a `Positive` shifts its logarithm, a `Bounded` moves its value
    (clipped inside the bounds) and maps it back, a plain number is multiplied. A value
    of exactly 0 has no scale of its own: it moves by up to ±(spread − 1) times its
    `scale` (the column scaling: the change that moves the residual by about one
    unit).
    """
    if starts < 1:
        raise ValueError(f"`starts` must be >= 1, got {starts}.")
    if not spread >= 1:
        raise ValueError(f"`spread` must be >= 1, got {spread}.")
    key = jax.random.key(0) if key is None else key
    log_spread = float(np.log(spread))
    leaves, treedef = jax.tree.flatten(constrained, is_leaf=is_parameter)
    scales = iter(jax.tree.leaves(scale))
    varied = []
    for k, p in enumerate(leaves):
        if isinstance(p, Fixed) or not (is_parameter(p) or eqx.is_inexact_array(p)):
            varied.append(p)
            continue
        value = p.value() if is_parameter(p) else p
        u = jax.random.uniform(
            jax.random.fold_in(key, k), (starts - 1,) + jnp.shape(value), minval=-1.0
        )
        s = next(scales)
        if isinstance(p, Positive):
            varied.append(
                eqx.tree_at(lambda q: q.log_value, p, p.log_value + u * log_spread)
            )
        elif isinstance(p, Bounded):
            width = p.upper - p.lower
            moved = jnp.clip(
                value * jnp.exp(u * log_spread),
                p.lower + 1e-6 * width,
                p.upper - 1e-6 * width,
            )
            fraction = (moved - p.lower) / width
            varied.append(
                eqx.tree_at(
                    lambda q: q.raw, p, jnp.log(fraction) - jnp.log1p(-fraction)
                )
            )
        else:
            varied.append(
                jnp.where(p == 0, p + u * (spread - 1) * s, p * jnp.exp(u * log_spread))
            )
    others = jax.tree.unflatten(treedef, varied)
    spec = free_filter(constrained)
    first = eqx.filter(constrained, spec)
    rest = eqx.filter(others, free_filter(others))
    return jax.tree.map(lambda a, b: jnp.concatenate([a[None], b]), first, rest)


# ---------------------------------------------------------------------------------------
# The loop


def _lm_fn(y, args, columns=None):
    """optimistix's residual function. Its aux is (½‖r‖², y): the loss paired with the
    point it belongs to, whatever step's aux `solver.step` returns. `columns`: the
    devices its Jacobian's columns are split over (`value_and_jacobian`), or None."""
    residuals_fn, static, data, extra = args

    # The residual carries its own materialised Jacobian: optimistix linearises the
    # residual and lineax then materialises that linearisation column by column, which
    # measured 10x slower than one `jacfwd` (all columns in one vectorised forward
    # pass). With this rule its linearisation is a matrix product.
    @jax.custom_jvp
    def residual(y):
        return traced_once(residuals_fn, y, static, data, extra)

    @residual.defjvp
    def residual_jvp(primals, tangents):
        (y,), (ty,) = primals, tangents
        r, jac = value_and_jacobian(residuals_fn, y, static, data, extra, columns)
        out = sum(
            jnp.tensordot(j, t, axes=t.ndim)
            for j, t in zip(jax.tree.leaves(jac), jax.tree.leaves(ty), strict=True)
        )
        return r, out

    r = residual(y)
    return r, (0.5 * jnp.sum(r**2), y)


_OPTIONS = {"jac": "fwd"}


@functools.cache
def _lm_fn_by_columns(columns: Mesh):
    """`_lm_fn` with its Jacobian's columns split over `columns` (one function per
    mesh, so that a step traced with it is traced once)."""
    return functools.partial(_lm_fn, columns=columns)


def _init(solver, ys, args, data_axis, chunk, mesh):
    """The solver's state at the starts `ys` (a batch, as `_step` takes them).

    Module-level and jitted on their arguments. An optimistix solver's state holds a
    jaxpr (static, compared by identity): only its arrays cross the jit boundary,
    with the static part from here passed unchanged each step, so the compiled step
    is reused. A `FastLevenbergMarquardt`'s state is arrays only, and its program is
    kept on disk as the step's is (`cached`): the state needs the residual's length,
    which only tracing the model tells, and a second `jaxmr fit` of the same shapes
    read the step back but traced the model here for it (0.2-0.4 s of its 1.8 s of
    compilation on the 30 UTFSM files)."""
    init = _fast_init if isinstance(solver, FastLevenbergMarquardt) else _any_init
    return init(solver, ys, args, data_axis, chunk, mesh)


def _initial_states(solver, ys, args, data_axis, chunk, mesh):
    def one(y, args):
        f_struct, aux_struct = jax.eval_shape(lambda: _lm_fn(y, args))
        return solver.init(_lm_fn, y, args, _OPTIONS, f_struct, aux_struct, frozenset())

    return _over_batch(one, (ys,), args, data_axis, chunk, mesh)


_any_init = eqx.filter_jit(_initial_states)


def _fast_state_like(solver, ys, *_):
    """A `FastLevenbergMarquardt` state's structure (`_fast_init`'s `cached`), which
    does not depend on the residual's length: its init's shapes, for a residual of
    one."""
    y = jax.tree.map(lambda a: jax.ShapeDtypeStruct(a.shape[1:], a.dtype), ys)
    dtype = jax.tree.leaves(ys)[0].dtype
    one = jax.ShapeDtypeStruct((1,), dtype)
    aux = (jax.ShapeDtypeStruct((), dtype), y)
    return jax.eval_shape(
        lambda y: solver.init(None, y, None, None, one, aux, frozenset()), y
    )


_fast_init = cached(_fast_state_like)(_initial_states)


# The step's outputs: the points, the state's arrays, the losses, the points they
# belong to, and the flags (their structure, for a step read back: `cached`).
@cached(lambda solver, ys, dynamic, *_: (ys, dynamic, 0, ys, 0, 0))
def _step(
    solver, ys, dynamic, static_state, args, data_axis, chunk, mesh, columns=None
):
    # `columns` (a `column_mesh`, for one unbatched member): the devices its
    # Jacobian's columns are split over.
    if columns is not None and not _unbatched((ys,), data_axis, chunk):
        raise ValueError("a Jacobian split by columns is for one unbatched member.")
    fn = _lm_fn if columns is None else _lm_fn_by_columns(columns)

    def one(y, dyn, args):
        state = eqx.combine(dyn, static_state)
        y, state, (loss, at) = solver.step(fn, y, args, _OPTIONS, state, frozenset())
        done, result = solver.terminate(fn, y, args, _OPTIONS, state, frozenset())
        failed = result != optx.RESULTS.successful
        return y, eqx.filter(state, eqx.is_array), loss, at, done, failed

    return _over_batch(one, (ys, dynamic), args, data_axis, chunk, mesh)


def _over_batch(one, members, args, data_axis, chunk, mesh):
    """`one(*member, args)` vmapped over axis 0 of `members` (and of the data in
    `args` when `data_axis` is 0). With `chunk`, the batch runs `chunk` members at a
    time, one chunk after another (`lax.map`), on each device's own shard of `mesh`
    (`shard_map`; the batch is spread over it, or `mesh` is None): every compiled
    operation then has the same shape whatever the batch's size and its split over
    devices and processes, so each member's result is the same bits in every layout.
    (One vmap over the whole batch is not: 256 brake fits in one process and 128 in
    each of two differed in the last bits, and a fit on a flat valley then ended
    elsewhere.)

    A batch of one without `chunk` (a fit from one start) runs unbatched, its outputs
    given the batch axis after: under `vmap` a batch of one simulated 1.5-3x slower
    (the Bouc–Wen benchmark's residual 8 ms against 23 ms, its Jacobian 35 ms against
    50 ms)."""
    fn, static, data, extra = args
    if _unbatched(members, data_axis, chunk):
        out = one(*jax.tree.map(lambda a: a[0], members), (fn, static, data, extra))
        return jax.tree.map(lambda a: a[None] if eqx.is_array(a) else a, out)

    def run(members, data, extra):
        return eqx.filter_vmap(
            lambda *a: one(*a[:-2], (fn, static, a[-2], a[-1])),
            in_axes=(0,) * len(members) + (data_axis, None),
        )(*members, data, extra)

    if chunk is None:
        return run(members, data, extra)
    # Chunks serve `fit_each`, whose problems carry their own data: the members and
    # the data are split, the column scale `extra` is shared (arrays cross `shard_map`).
    if data_axis != 0:
        raise ValueError("chunked batches need batched data (data_axis 0).")
    own, own_static = eqx.partition((members, data), eqx.is_array)
    shared, shared_static = eqx.partition(extra, eqx.is_array)
    out_static = []  # the output's non-array part, seen when the chunk is traced

    def local(own, shared):
        ex = eqx.combine(shared, shared_static)
        n = jax.tree.leaves(own)[0].shape[0]

        def one_chunk(c):
            ms, d = eqx.combine(c, own_static)
            out, rest = eqx.partition(run(ms, d, ex), eqx.is_array)
            out_static.append(rest)
            return out

        split = lambda a: a.reshape((n // chunk, chunk) + a.shape[1:])
        out = jax.lax.map(one_chunk, jax.tree.map(split, own))
        return jax.tree.map(lambda a: a.reshape((n,) + a.shape[2:]), out)

    if mesh is None:
        out = local(own, shared)
    else:
        out = jax.shard_map(
            local,
            mesh=mesh,
            in_specs=(PartitionSpec(MESH_AXIS), PartitionSpec()),
            out_specs=PartitionSpec(MESH_AXIS),
            check_vma=False,
        )(own, shared)
    return eqx.combine(out, out_static[0])


def _unbatched(members, data_axis, chunk) -> bool:
    """Whether `_over_batch` runs `members` unbatched: one member, its data shared,
    no chunks."""
    return (
        chunk is None
        and data_axis is None
        and (jax.tree.leaves(members)[0].shape[0] == 1)
    )


# A member has also stalled when this many *accepted* steps (steps that lowered its
# loss) since its last gain of a relative `ftol` have not made another, and the
# Gauss–Newton model at its best point promises less than that gain too
# (`FastLevenbergMarquardt`'s `available`, its undamped step's predicted reduction;
# other solvers do not say, and stall on the steps alone). Small accepted steps while
# the region grows tenfold after each mean the bottom is reached: on the 30 UTFSM
# records the joint fit crept for 8 more steps (12 s) after its last gain of 1e-4,
# improving the loss by 3e-6 in all, its model promising 1e-5 to 1e-7 of the loss.
# But small steps alone do not say so: on the UTFSM training records LuGre made three
# accepted steps of less than 1e-4 while its model still promised 1.2 %, and crawled
# on from a loss of 0.0321 to 0.0249. The promise alone is no test either: a promise
# below `ftol` may still be a parameter about one standard error from the optimum
# with 10 000 white residuals (a step of one standard error changes the loss by about
# 1/N of it), which the accepted steps that follow still remove.
ACCEPTED_PATIENCE = 3


def check_budget(max_steps, patience) -> None:
    """`max_steps` and `patience` are integers >= 1 (0 steps had reported a fit
    "failed: every evaluated point gave a non-finite loss"): checked by every entry
    point of `iterate` (`fit`, `fit_each`, `fit_system`) before anything compiles."""
    for name, value in (("max_steps", max_steps), ("patience", patience)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise TypeError(f"`{name}` must be an integer, got {value!r}.")
        if value < 1:
            raise ValueError(f"`{name}` must be at least 1, got {value!r}.")


def iterate(
    solver,
    ys,
    args,
    data_axis,
    max_steps,
    patience,
    ftol,
    report,
    chunk=None,
    mesh=None,
    stop=None,
    first=None,
    columns=None,
):
    """Levenberg–Marquardt on a batch of problems, stepped from Python.

    Axis 0 of `ys` is the batch (starts, or independent problems when `data_axis` is
    0 and the data in `args` are batched too). Keeps each member's best parameters,
    stops each on its own convergence, failure or stall (no relative improvement of
    `ftol` in `patience` steps, or in `ACCEPTED_PATIENCE` accepted steps with a model
    that promises no more). `chunk`,
    `mesh`: see `_over_batch`. `stop`: a `threading.Event` (anything with `is_set()`)
    checked after every step: once set, the loop stops with the best parameters so
    far (`StopReason.INTERRUPTED`; at least one step, the starts' evaluation, is
    made). A `KeyboardInterrupt` does the same; any other exception propagates (a
    programming error is not a fit result). `first`: its first step, made before
    (`scale_and_first_step`'s `FirstStep` from the start `ys`), or None. `columns`:
    a `column_mesh` for a batch of one, its arrays whole on each of its devices.

    Returns the best ys and one `Outcome` per member (its best loss, the history of
    the batch's best loss (of its own, for independent problems: `data_axis` 0),
    the steps taken, its `StopReason`).
    """
    if first is None:
        dynamic, static_state = eqx.partition(
            _init(solver, ys, args, data_axis, chunk, mesh), eqx.is_array
        )
    else:
        dynamic, static_state = None, first.static_state
    n = jax.tree.leaves(ys)[0].shape[0]
    best_loss = np.full(n, np.inf)
    best_y = ys
    history, last_improvement = [], np.zeros(n, dtype=int)
    own = []  # every member's best loss after each step
    accepted_since = np.zeros(n, dtype=int)
    reference = np.full(n, np.inf)
    converged = np.zeros(n, dtype=bool)
    failed = np.zeros(n, dtype=bool)
    stalled = np.zeros(n, dtype=bool)
    steps = np.zeros(n, dtype=int)  # each member's own, up to its stop
    interrupted = False
    try:
        for k in range(1, max_steps + 1):
            if k == 1 and first is not None:
                ys, dynamic, loss, at, done, bad = first.outputs
            else:
                ys, dynamic, loss, at, done, bad = _step(
                    solver,
                    ys,
                    dynamic,
                    static_state,
                    args,
                    data_axis,
                    chunk,
                    mesh,
                    columns,
                )
            # Every process reads the whole batch (one collective when it is spread
            # over processes), so all take the same decisions below.
            loss, done, bad = (to_host(a) for a in (loss, done, bad))
            # What the Gauss–Newton model promises at each member's best point.
            available = getattr(dynamic, "available", None)
            available = None if available is None else to_host(available)
            # A member that has stopped keeps its result: the batch steps on for the
            # others, and how long it does must not change this member's answer.
            active = ~(converged | failed | stalled)
            steps = np.where(active, k, steps)
            better = active & np.isfinite(loss) & (loss < best_loss)
            best_y = _keep_better(better, at, best_y)
            best_loss = np.where(better, loss, best_loss)
            improved = best_loss < reference * (1 - ftol)
            reference = np.where(improved, best_loss, reference)
            last_improvement = np.where(improved, k, last_improvement)
            accepted_since = np.where(improved, 0, accepted_since + better)
            history.append(float(np.min(best_loss)))
            own.append(best_loss.copy())
            report(k, float(np.min(best_loss)))
            failed |= active & bad
            converged |= active & done & ~bad
            at_noise_floor = accepted_since >= ACCEPTED_PATIENCE
            if available is not None:
                at_noise_floor &= available <= ftol * loss
            stalled |= active & (((k - last_improvement) >= patience) | at_noise_floor)
            if not np.any(~(converged | failed | stalled)):
                break
            if stop is not None and stop.is_set():
                interrupted = True
                break
    except KeyboardInterrupt:
        interrupted = True

    def why(j) -> StopReason:
        # The caller asked to stop: the whole batch of starts of one fit, but of
        # independent problems (`fit_each`) only those still running; one that had
        # stopped keeps its own verdict (all were "interrupted" before).
        own_stop = converged[j] or failed[j] or stalled[j]
        if interrupted and (data_axis is None or not own_stop):
            return StopReason.INTERRUPTED
        if not np.isfinite(best_loss[j]):
            return StopReason.NONFINITE
        if failed[j]:
            return StopReason.SOLVER_FAILED
        if converged[j]:
            return StopReason.TOLERANCE
        if stalled[j]:
            return StopReason.STALLED
        return StopReason.MAX_STEPS

    def history_of(j) -> tuple[float, ...]:
        # Starts of one fit share the batch's best; independent problems
        # (`fit_each`: the data batched too) each have their own, up to their stop.
        if data_axis is None:
            return tuple(history)
        return tuple(float(losses[j]) for losses in own[: max(int(steps[j]), 1)])

    return best_y, [
        Outcome(float(best_loss[j]), history_of(j), int(steps[j]), why(j))
        for j in range(n)
    ]


@eqx.filter_jit
def _keep_better(better, new, old):
    """Each member's `new` point where `better`, else its `old` one (one compiled
    program, not an eager `where` per leaf)."""
    return jax.tree.map(
        lambda n, o: jnp.where(jnp.reshape(better, (-1,) + (1,) * (n.ndim - 1)), n, o),
        new,
        old,
    )


class ProgressPrinter:
    """A fit's `progress(step, loss)` that prints a line now and then: every
    `seconds` [s] of wall time (`None`: not by time) and every `steps`-th step
    (`None`: not by count), e.g. `steps=10` for a log file, which the 2 s of a
    terminal would leave silent for minutes in a quiet fit. `label` (a plain
    attribute, may change between fits) and `indent` start the line."""

    def __init__(
        self,
        label: str = "fit",
        *,
        seconds: float | None = 2.0,
        steps: int | None = None,
        indent: str = "  ",
    ):
        self.label, self.indent = label, indent
        self.seconds, self.steps = seconds, steps
        self._printed = time.monotonic()

    def __call__(self, step: int, loss: float) -> None:
        now = time.monotonic()
        due = (self.steps is not None and step % self.steps == 0) or (
            self.seconds is not None and now - self._printed >= self.seconds
        )
        if due:
            line = f"{self.indent}{self.label} step {step:4d}: loss {loss:.6g}"
            print(line, flush=True)
            self._printed = now


def progress_printer(progress, label: str = "fit"):
    """`progress(step, loss)` from `True` (a `ProgressPrinter`: a line every 2 s),
    `False` or a callable."""
    if callable(progress):
        return progress
    if not progress:
        return lambda step, loss: None
    return ProgressPrinter(label)
