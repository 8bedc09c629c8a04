r"""Differentiable Lyapunov and Riccati solvers, and the LQR gain.

Both are small dense solvers for the few-state models of semi-active control (a quarter
car has 4 states): they favour exactness and clean derivatives over the $O(n^3)$ Schur
methods of SLICOT/scipy, which JAX does not differentiate.
"""

import equinox as eqx
import jax
import jax.numpy as jnp

from .._custom_types import Array, Float


def _check_square(name: str, M, n: int | None = None) -> None:
    if M.ndim != 2 or M.shape[0] != M.shape[1] or (n is not None and M.shape[0] != n):
        want = "a square matrix" if n is None else f"an ({n}, {n}) matrix"
        raise ValueError(f"`{name}` must be {want}, got shape {M.shape}.")


def _lyapunov(A, Q):
    # Row-major vec: vec(M X N) = (M ⊗ Nᵀ) vec(X), so AᵀP + PA = (Aᵀ ⊗ I + I ⊗ Aᵀ) vec(P).
    # An n²×n² dense solve: exact to rounding, differentiable by JAX's own rules, and
    # cheap for the n ≤ ~20 of a vehicle model (a Bartels–Stewart solver would need a
    # real Schur form, which JAX cannot differentiate).
    n = A.shape[0]
    eye = jnp.eye(n, dtype=A.dtype)
    kron = jnp.kron(A.T, eye) + jnp.kron(eye, A.T)
    P = jnp.linalg.solve(kron, -Q.reshape(n * n)).reshape(n, n)
    return 0.5 * (P + P.T)


@eqx.filter_jit
def solve_lyapunov(
    A: Float[Array, "n n"], Q: Float[Array, "n n"]
) -> Float[Array, "n n"]:
    r"""Solve the continuous Lyapunov equation $A^\top P + P A = -Q$ for $P$.

    (The control convention; scipy's `solve_continuous_lyapunov(a, q)` solves
    $a X + X a^\top = q$, i.e. this with $a = A^\top$, $q = -Q$.) For a stable $A$ and
    $Q \succ 0$, $P \succ 0$ and $V = x^\top P x$ is a Lyapunov function of
    $\dot x = A x$. Solved as one $n^2 \times n^2$ linear system; jittable, vmappable,
    differentiable in $A$ and $Q$.

    **Arguments:**

    - `A`: the system matrix, $(n, n)$ [1/s]; no two eigenvalues may sum to zero
      (e.g. an undamped mode), else there is no unique solution.
    - `Q`: the symmetric weight, $(n, n)$ (its symmetric part is used).

    **Returns:** the symmetric $P$, $(n, n)$ ($P$ has $Q$'s unit times seconds).
    """
    A = jnp.asarray(A)
    Q = jnp.asarray(Q)
    _check_square("A", A)
    _check_square("Q", Q, A.shape[0])
    P = _lyapunov(A, 0.5 * (Q + Q.T))
    return eqx.error_if(
        P,
        ~jnp.all(jnp.isfinite(P)),
        "solve_lyapunov: no unique solution: `A` has eigenvalues λi + λj = 0 (an "
        "undamped or unstable mode); add damping or stabilise `A` first.",
    )


def _sign(Z, max_steps: int = 100):
    # Newton's iteration for the matrix sign function with determinant scaling
    # (Byers 1987), Z ← (cZ + (cZ)⁻¹)/2, c = |det Z|^(-1/m): quadratic convergence once
    # scaled, and scale-free enough for the badly scaled matrices of vehicle models
    # (tyre stiffness over wheel mass ~ 5000 s⁻² beside a body mode of 50 s⁻²).
    m = Z.shape[0]
    eps = jnp.finfo(Z.dtype).eps
    tol = 10 * m * jnp.sqrt(eps)

    def cond(carry):
        k, _, change = carry
        return (k < max_steps) & (change > tol)

    eye = jnp.eye(m, dtype=Z.dtype)

    def body(carry):
        k, Z, _ = carry
        # One LU gives both the determinant and the inverse.
        lu, pivots = jax.scipy.linalg.lu_factor(Z)
        c = jnp.exp(-jnp.sum(jnp.log(jnp.abs(jnp.diagonal(lu)))) / m)
        Z_next = 0.5 * (c * Z + jax.scipy.linalg.lu_solve((lu, pivots), eye) / c)
        change = jnp.sum(jnp.abs(Z_next - Z)) / jnp.sum(jnp.abs(Z_next))
        return k + 1, Z_next, change

    start = (jnp.array(0), Z, jnp.array(jnp.inf, dtype=Z.dtype))
    _, Z, _ = jax.lax.while_loop(cond, body, start)
    # Past the tolerance the iteration is quadratic: two unscaled steps reach rounding.
    for _ in range(2):
        Z = 0.5 * (Z + jnp.linalg.inv(Z))
    return Z


def _newton_kleinman(A, G, Q, P):
    # One Newton step on the Riccati residual: quadratic convergence from a stabilising
    # guess; it polishes the sign-function solution to the accuracy of a Lyapunov solve.
    Acl = A - G @ P
    return _lyapunov(Acl, Q + P @ G @ P)


@jax.custom_jvp
def _care(A, G, Q):
    n = A.shape[0]
    H = jnp.block([[A, -G], [-Q, -A.T]])
    W = _sign(H)
    eye = jnp.eye(n, dtype=A.dtype)
    # The stable invariant subspace of H is range [I; P], and sign(H) = -I on it:
    # (W + I)[I; P] = 0, an overdetermined but consistent system for P, solved by its
    # normal equations: their squared conditioning is repaired by the Newton steps.
    lhs = jnp.concatenate([W[:n, n:], W[n:, n:] + eye], axis=0)
    rhs = -jnp.concatenate([W[:n, :n] + eye, W[n:, :n]], axis=0)
    P = jnp.linalg.solve(lhs.T @ lhs, lhs.T @ rhs)
    P = 0.5 * (P + P.T)
    for _ in range(2):
        P = _newton_kleinman(A, G, Q, P)
    return P


@_care.defjvp
def _care_jvp(primals, tangents):
    # Implicit differentiation of AᵀP + PA − PGP + Q = 0 (the iterations above are
    # never differentiated): Aclᵀ dP + dP Acl = −(dAᵀP + P dA − P dG P + dQ) with the
    # stable Acl = A − GP, one more Lyapunov solve, linear in the tangents, so reverse
    # mode follows by transposition.
    A, G, Q = primals
    dA, dG, dQ = tangents
    P = _care(A, G, Q)
    Acl = A - G @ P
    rhs = dA.T @ P + P @ dA - P @ dG @ P + dQ
    return P, _lyapunov(Acl, rhs)


def _riccati_inputs(A, B, Q, R, N):
    A, B, Q, R = (jnp.asarray(M) for M in (A, B, Q, R))
    _check_square("A", A)
    n = A.shape[0]
    if B.ndim == 1:
        B = B[:, None]
    if B.ndim != 2 or B.shape[0] != n:
        raise ValueError(f"`B` must be an ({n}, m) matrix, got shape {B.shape}.")
    m = B.shape[1]
    if R.ndim == 0:
        R = R[None, None]
    _check_square("Q", Q, n)
    _check_square("R", R, m)
    N = jnp.zeros((n, m), dtype=A.dtype) if N is None else jnp.asarray(N)
    if N.ndim == 1:
        N = N[:, None]
    if N.shape != (n, m):
        raise ValueError(f"`N` must be an ({n}, {m}) matrix, got shape {N.shape}.")
    Q = 0.5 * (Q + Q.T)
    R = 0.5 * (R + R.T)
    return A, B, Q, R, N


def _checked_weights(Q, R, N):
    """`Q`, `R` with runtime checks: R positive definite and the cost's whole weight
    [[Q, N], [Nᵀ, R]] positive semidefinite (to rounding). An indefinite weight
    has no minimum: the sign-function solve still returned a P, and with R = −1 a
    gain of 1e7 whose closed loop had an eigenvalue at +2e5."""
    whole = jnp.linalg.eigvalsh(jnp.block([[Q, N], [N.T, R]]))
    rounding = 1e-10 * jnp.max(jnp.abs(whole))
    R = eqx.error_if(
        R,
        jnp.min(jnp.linalg.eigvalsh(R)) <= 0,
        "lqr/solve_riccati: `R` must be positive definite (every eigenvalue > 0): "
        "the input's weight.",
    )
    Q = eqx.error_if(
        Q,
        jnp.min(whole) < -rounding,
        "lqr/solve_riccati: the state weight `Q` (with the cross weight `N`) must be "
        "positive semidefinite (every eigenvalue of [[Q, N], [Nᵀ, R]] >= 0): an "
        "indefinite weight rewards the states it should penalise.",
    )
    return Q, R


def _solve(A, B, Q, R, N):
    Q, R = _checked_weights(Q, R, N)
    # The cross term folds into A and Q: with u = v − R⁻¹Nᵀx the cost has no cross term.
    R_inv_BT = jnp.linalg.solve(R, B.T)
    R_inv_NT = jnp.linalg.solve(R, N.T)
    A_hat = A - B @ R_inv_NT
    Q_hat = Q - N @ R_inv_NT
    G = B @ R_inv_BT
    P = _care(A_hat, 0.5 * (G + G.T), 0.5 * (Q_hat + Q_hat.T))
    return eqx.error_if(
        P,
        ~jnp.all(jnp.isfinite(P)),
        "solve_riccati: no stabilising solution: (A, B) must be stabilisable, the "
        "weights detectable (no undamped mode left unweighted by Q) and R positive "
        "definite.",
    )


@eqx.filter_jit
def solve_riccati(
    A: Float[Array, "n n"],
    B: Float[Array, "n m"] | Float[Array, " n"],
    Q: Float[Array, "n n"],
    R: Float[Array, "m m"] | Float[Array, ""],
    N: Float[Array, "n m"] | Float[Array, " n"] | None = None,
) -> Float[Array, "n n"]:
    r"""Solve the continuous-time algebraic Riccati equation for its stabilising
    solution:
    $$A^\top P + P A - (P B + N) R^{-1} (B^\top P + N^\top) + Q = 0.$$

    The method: the matrix sign function of the Hamiltonian
    $H = \begin{bmatrix} A & -BR^{-1}B^\top \\ -Q & -A^\top\end{bmatrix}$ (scaled
    Newton iteration; its stable invariant subspace is spanned by $[I; P]$), then two
    Newton–Kleinman steps, each a Lyapunov solve. Jittable and vmappable; derivatives
    by implicit differentiation of the equation (one Lyapunov solve with the closed
    loop $A - BR^{-1}(B^\top P + N^\top)$), in forward and reverse mode, with respect
    to `A`, `B`, `Q`, `R` and `N`.

    **Arguments:**

    - `A`: the system matrix, $(n, n)$.
    - `B`: the input matrix, $(n, m)$ (a vector for one input).
    - `Q`: the state weight, $(n, n)$, symmetric (its symmetric part is used).
    - `R`: the input weight, $(m, m)$ (a scalar for one input), positive definite.
    - `N`: the cross weight, $(n, m)$ (cost $x^\top Q x + 2 x^\top N u + u^\top R u$);
      default 0.

    **Returns:** the symmetric stabilising $P$, $(n, n)$.
    """
    return _solve(*_riccati_inputs(A, B, Q, R, N))


@eqx.filter_jit
def lqr(
    A: Float[Array, "n n"],
    B: Float[Array, "n m"] | Float[Array, " n"],
    Q: Float[Array, "n n"],
    R: Float[Array, "m m"] | Float[Array, ""],
    N: Float[Array, "n m"] | Float[Array, " n"] | None = None,
) -> tuple[Float[Array, "m n"], Float[Array, "n n"]]:
    r"""Linear-quadratic regulator: the state feedback $u = -K x$ minimising
    $\int_0^\infty x^\top Q x + 2 x^\top N u + u^\top R u \; dt$ for
    $\dot x = A x + B u$.

    $K = R^{-1}(B^\top P + N^\top)$ with $P$ from `solve_riccati` (same arguments,
    same differentiability). Agrees with python-control's `lqr(A, B, Q, R, N)`.

    **Returns:** `(K, P)`: the gain, $(m, n)$ [input unit per state unit], and $P$.
    """
    A, B, Q, R, N = _riccati_inputs(A, B, Q, R, N)
    P = _solve(A, B, Q, R, N)
    K = jnp.linalg.solve(R, B.T @ P + N.T)
    return K, P
