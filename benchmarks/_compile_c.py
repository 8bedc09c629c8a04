"""A controller exported by `jaxmr.export_c`, compiled with the system C compiler into
a shared library with a small driver, and called through ctypes (the tests'
equality checks, tests/test_export.py, and the timing, export_c.py).

The driver's functions, over the exported `<name>_init` and `<name>_step`:

- `run(n, inputs, commands)`: init at the first row, then one step per row of the
  `n` x `N_INPUTS` array `inputs`, the commands [A] into `commands`;
- `state_size()`, `init(state, inputs)` and `step(before, after, inputs)`: the state
  as bytes outside the library, so that a step is a pure function (`after` the
  state past `before`)."""

import ctypes
import shutil
import subprocess
from pathlib import Path

import numpy as np

FLAGS = ("-std=c99", "-O2", "-Wall", "-Werror")

_DRIVER = """\
#include <stddef.h>
#include <string.h>

#include "{name}.h"

size_t state_size(void) {{ return sizeof({name}_state); }}

void run(int n, const double *inputs, double *commands)
{{
    {name}_state state;
    int k;
    {name}_init(&state, inputs);
    for (k = 0; k < n; ++k)
        commands[k] = {name}_step(&state, inputs + (size_t)k * {macro}_N_INPUTS);
}}

void init(void *state, const double *inputs) {{ {name}_init(state, inputs); }}

double step(const void *before, void *after, const double *inputs)
{{
    memcpy(after, before, sizeof({name}_state));
    return {name}_step(after, inputs);
}}
"""


def compiler() -> str:
    """The system C compiler (`cc`); a clear error where there is none."""
    found = shutil.which("cc")
    if found is None:
        raise RuntimeError(
            "no C compiler: `cc` is not on PATH. The exported C is checked by "
            "compiling it; install one (e.g. apt-get install gcc)."
        )
    return found


class CompiledController:
    """The exported controller `name` in `folder`, compiled (with `FLAGS`, `-lm`)."""

    def __init__(self, folder, name: str):
        folder = Path(folder)
        driver = folder / f"{name}_driver.c"
        driver.write_text(_DRIVER.format(name=name, macro=name.upper()))
        library = folder / f"lib{name}.so"
        subprocess.run(
            [
                compiler(),
                *FLAGS,
                "-shared",
                "-fPIC",
                "-o",
                str(library),
                str(folder / f"{name}.c"),
                str(driver),
                "-lm",
            ],
            check=True,
            capture_output=True,
            text=True,
        )
        lib = ctypes.CDLL(str(library))
        pointer = ctypes.c_void_p
        lib.state_size.restype = ctypes.c_size_t
        lib.run.argtypes = [ctypes.c_int, pointer, pointer]
        lib.run.restype = None
        lib.init.argtypes = [pointer, pointer]
        lib.init.restype = None
        lib.step.argtypes = [pointer, pointer, pointer]
        lib.step.restype = ctypes.c_double
        self.lib = lib
        self.state_size = int(lib.state_size())

    def run(self, inputs) -> np.ndarray:
        """The commands [A] for the rows of `inputs` (samples x measurements)."""
        inputs = np.ascontiguousarray(inputs, dtype=np.float64)
        commands = np.empty(inputs.shape[0])
        self.lib.run(inputs.shape[0], inputs.ctypes.data, commands.ctypes.data)
        return commands

    def init(self, inputs) -> np.ndarray:
        """The state (bytes) before the first sample, at its `inputs`."""
        inputs = np.ascontiguousarray(inputs, dtype=np.float64)
        state = np.zeros(self.state_size, np.uint8)
        self.lib.init(state.ctypes.data, inputs.ctypes.data)
        return state

    def step(self, state, inputs) -> tuple[np.float64, np.ndarray]:
        """The command [A] and the next state, `state` left as it was."""
        before = np.ascontiguousarray(state, dtype=np.uint8)
        inputs = np.ascontiguousarray(inputs, dtype=np.float64)
        after = np.empty_like(before)
        command = self.lib.step(
            before.ctypes.data, after.ctypes.data, inputs.ctypes.data
        )
        return np.float64(command), after
