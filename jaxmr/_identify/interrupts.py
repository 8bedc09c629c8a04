"""Ctrl-C while a finished fit computes its report: the fitted model is not lost.

`fit` and `fit_each` stop their Levenberg–Marquardt loop at a Ctrl-C and keep the
best parameters so far. After the loop they still simulate the fitted model and
compute its Jacobian (seconds, more with `statistics_refinement`): a Ctrl-C there
raised `KeyboardInterrupt` out of the fit and every finished fit was lost (a user's
trial: 16 `fit_each` results, and a `fit` that had reached its last step).
`finishing` defers the first Ctrl-C of that stretch, saying so; a second one
interrupts as usual.
"""

import contextlib
import signal
import sys
import threading


@contextlib.contextmanager
def finishing(who: str):
    """While the body runs, the first Ctrl-C prints a note and is set aside, a
    second raises `KeyboardInterrupt`. Only where Python's own handler is in place
    and in the main thread (signal handlers live there): a program's own SIGINT
    handling (the command line's) is left alone."""
    if (
        threading.current_thread() is not threading.main_thread()
        or signal.getsignal(signal.SIGINT) is not signal.default_int_handler
    ):
        yield
        return
    count = 0

    def handle(signum, frame):
        nonlocal count
        count += 1
        if count > 1:
            raise KeyboardInterrupt
        print(
            f"{who}: Ctrl-C while the fitted model's errors are computed: finishing "
            "them (seconds) so that the fit is not lost; Ctrl-C again to abandon it",
            file=sys.stderr,
            flush=True,
        )

    previous = signal.signal(signal.SIGINT, handle)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
