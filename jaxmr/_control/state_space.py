"""The linear quarter car, for model-based laws (LQR, Lyapunov)."""

import jax.numpy as jnp

from .._custom_types import Array, Float, ScalarLike
from .._systems.quarter_car import QuarterCar

# The measurements that make up the state of the 4-state models, in order.
QUARTER_CAR_STATE = (
    "body_position",
    "body_velocity",
    "wheel_position",
    "wheel_velocity",
)


# The absolute positions among them, which no car sensor gives: a law that reads one
# declares it (`reads_positions`), so that its controller's estimator estimates them.
POSITIONS = ("body_position", "wheel_position")


def measured_state(measurement: dict) -> Float[Array, "4"]:
    """The state $x = (z_s, \\dot z_s, z_u, \\dot z_u)$ [m, m/s] from a controller's
    measurements (full-state feedback: the laws assume these four are measured or
    estimated; `VelocityEstimator` estimates them inside an
    `ObserverBasedController`)."""
    return jnp.stack([measurement[name] for name in QUARTER_CAR_STATE])


def reads_positions(law) -> bool:
    """Whether the controller `law` reads an absolute position (`POSITIONS`): it
    says so (its attribute `reads_positions`, a class attribute True for the
    full-state laws and `Backstepping`; a law that wraps another may forward the
    other's) or its `features` (`ForceFeedback`'s) name one."""
    features = getattr(law, "features", None) or ()
    return bool(getattr(law, "reads_positions", False)) or any(
        name in POSITIONS for name in features
    )


def quarter_car_state_space(
    car: QuarterCar, damping: ScalarLike = 0.0
) -> tuple[Float[Array, "4 4"], Float[Array, "4 1"], Float[Array, "4 _"]]:
    r"""The linear quarter car $\dot x = A x + B u + E w$.

    States $x = (z_s, \dot z_s, z_u, \dot z_u)$ [m, m/s]; input $u$ the damper force
    $F$ [N] (positive when it resists extension $v = \dot z_s - \dot z_u > 0$, as in
    `QuarterCar`), so
    $$B = (0, -1/m_s, 0, 1/m_u)^\top.$$
    The disturbance $w$ is the road, $w = (z_r, \dot z_r)$ [m, m/s] with
    $E = (0, 0, 0, k_t/m_u;\; 0, 0, 0, c_t/m_u)^\top$, or for a force-excited car the
    wheel force [N], $E = (0, 0, 0, 1/m_u)^\top$. The parallel damping `cs`, `ct` is in
    $A$; the tyre is linear (no lift-off).

    **Arguments:**

    - `car`: a `QuarterCar`.
    - `damping`: viscous damping $c$ [N·s/m] to fold into $A$ besides `cs`, e.g. the
      damper's zero-current part, so that $A$ is stable (a Lyapunov design needs that);
      the input is then the rest of the damper force, $u = F - c v$. Default 0.

    **Returns:** `(A, B, E)`, shapes (4, 4), (4, 1), (4, 2) or (4, 1).
    """
    ms, mu, ks, kt, ct = car.ms, car.mu, car.ks, car.kt, car.ct
    cs = car.cs + jnp.asarray(damping, dtype=car.cs.dtype)
    zero = jnp.zeros_like(ms)
    one = jnp.ones_like(ms)
    A = jnp.stack(
        [
            jnp.stack([zero, one, zero, zero]),
            jnp.stack([-ks / ms, -cs / ms, ks / ms, cs / ms]),
            jnp.stack([zero, zero, zero, one]),
            jnp.stack([ks / mu, cs / mu, -(ks + kt) / mu, -(cs + ct) / mu]),
        ]
    )
    B = jnp.stack([zero, -1 / ms, zero, 1 / mu])[:, None]
    if car.excitation == "force":
        E = jnp.stack([zero, zero, zero, 1 / mu])[:, None]
    else:
        E = jnp.stack(
            [
                jnp.stack([zero, zero, zero, kt / mu]),
                jnp.stack([zero, zero, zero, ct / mu]),
            ],
            axis=1,
        )
    return A, B, E
