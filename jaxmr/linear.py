"""Linear control: the linear quarter car and the differentiable solvers of linear-
quadratic design.

- `quarter_car_state_space`: the linear quarter car $\\dot x = A x + B u + E w$.
- `solve_lyapunov`, `solve_riccati`: the continuous Lyapunov and algebraic Riccati
  equations, exact and differentiable for the few states of a vehicle model.
- `lqr`: the LQR gain.

The model-based controllers (`jaxmr.ClippedOptimal`, `jaxmr.LyapunovController`) build
on these; use them directly to design a gain by hand or to differentiate through the
design.

```python
import jaxmr.linear

A, B, _ = jaxmr.linear.quarter_car_state_space(car)
K, P = jaxmr.linear.lqr(A, B, Q, R)  # the gain and the Riccati solution
```
"""

from ._control import (
    lqr as lqr,
    quarter_car_state_space as quarter_car_state_space,
    solve_lyapunov as solve_lyapunov,
    solve_riccati as solve_riccati,
)

__all__ = ["lqr", "quarter_car_state_space", "solve_lyapunov", "solve_riccati"]
