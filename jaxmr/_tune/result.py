"""What every tuner returns."""

import dataclasses

from .._control.base import AbstractController
from .._integrate import FixedStep
from .._systems.base import AbstractSystem


@dataclasses.dataclass(frozen=True, eq=False)
class TuneResult:
    """The outcome of `tune`, `random_search` or `cma_es`.

    **Attributes:**

    - `system`, `controller`: the tuned pair, with the hard law (the controller's
      `temperature`, if it has one, as it was given: the relaxation used while tuning
      is not kept).
    - `values`: the tuned parameters, in the order `parameters` returns them.
    - `loss`: the best training loss of the hard law (mean objective over the
      training roads, and over the damper samples when given: the worst
      `worst_share` of them).
    - `initial_loss`: the hard law's training loss at the start.
    - `held_out_loss`: the returned pair's mean objective on the `validation` roads
      (over the samples as `loss` is; `None` when no roads were given).
    - `history`: the best loss after each iteration (a step of `tune`, a generation
      of `cma_es`, a candidate of `random_search`).
    - `simulations`: road simulations spent (a gradient evaluation of a batch of $B$
      runs counts $B$, like $B$ forward runs, although its backward pass costs about
      twice a forward run more; the hard-law checks of `tune` count too).
    - `seconds`: wall time, compilation included.
    - `reason`: why it stopped.
    - `integrator`: the RK4 substeps per sample its runs took (a `FixedStep`: the
      one given, or the one chosen from the damper's stiffness): pass it to
      `evaluate` or `simulate_system` to run the tuned pair at the very same steps.
    """

    system: AbstractSystem
    controller: AbstractController
    values: tuple
    loss: float
    initial_loss: float
    held_out_loss: float | None
    history: tuple[float, ...]
    simulations: int
    seconds: float
    reason: str
    integrator: FixedStep | None = None
