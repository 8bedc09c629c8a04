"""Traced programs kept on disk between processes: a fit's large programs exported
(`jax.export`) after their first trace, so that a later process with the same
shapes reads them back instead of tracing the model again.

JAX's persistent compilation cache keeps compiled executables, but finds them by the
lowered program, so a second `jaxmr fit` still traced and lowered every program
before reading its executable back: 0.9 of its 1.3-1.6 s of compilation on the 30
UTFSM files (the solver's step 0.3 s, the statistics' Jacobian 0.3 s, the reported
simulation 0.16 s). An exported program is read and lowered without running any of
the model's Python, then compiled through the same persistent cache.

Off unless a folder is set (`traced_programs_in`): the command line sets one inside its
compilation cache while a command runs; the library alone never writes anywhere. A
program is kept only when everything it depends on besides its array inputs is known
by value: the arguments' static parts (numbers, strings, NumPy arrays by their bytes,
equinox modules field by field, and functions and classes by name, only jaxmr's own
and those of the libraries below), the input arrays' shapes, types and placements,
jaxmr's own source (a digest of its files), and the versions of JAX and the
libraries it traces through. Anything else (a closure, a class of the user's, an
object without a value-based description) is traced as usual, never guessed at; so
is every call in a process of a multi-process job. A file that cannot be read back
(truncated, another version's) is ignored and written again.
"""

import contextlib
import dataclasses
import enum
import functools
import hashlib
import importlib.metadata
import os
import types
from collections.abc import Callable
from pathlib import Path

import equinox as eqx
import jax
import numpy as np

from .data._files import write_atomically

_FOLDER: Path | None = None
_MEMORY: dict[str, "jax.export.Exported | None"] = {}  # None: not exportable
# The libraries a fit's programs are traced through: a new version may trace the same
# call to another program.
_LIBRARIES = ("jax", "jaxlib", "equinox", "optimistix", "lineax", "diffrax", "numpy")


# Whose functions and classes a key may name: their code is in the key (jaxmr's source
# digest, the libraries' versions). A user's are not, and could change under a name.
_KNOWN_MODULES = ("jaxmr", "builtins", *_LIBRARIES)


@contextlib.contextmanager
def traced_programs_in(folder: str | os.PathLike | None):
    """Within the block, keep the fit's traced programs in `folder` and read them back
    from there: a later process (a second `jaxmr fit` of files of the same shapes)
    then skips tracing the model for the solver's initial state and step, the
    reported simulation and the statistics' Jacobian, about 0.8 s of a
    14-parameter fit's 1.5 s of compilation with a warm compilation cache. None:
    keep none. The previous setting comes back after the block.

    Pair it with JAX's persistent compilation cache (`jax_compilation_cache_dir`),
    which keeps what these programs compile to. A program is kept only when every
    argument that is not an array is known by value (jaxmr's own functions and
    classes, numbers, strings, NumPy arrays), and its key holds jaxmr's source and
    the versions of JAX, equinox, optimistix, lineax, diffrax and NumPy: a changed
    library or model traces anew. The folder (made when the first program is
    written, one file of tens of kB per program and shape) may be deleted at any
    time. The command line keeps them in the `programs` folder of its compilation
    cache.

    ```python
    with jaxmr.devices.traced_programs_in("~/.cache/my_fits/programs"):
        result = jaxmr.fit(model, experiments)
    ```
    """
    global _FOLDER
    previous = _FOLDER
    _FOLDER = None if folder is None else Path(folder).expanduser()
    try:
        yield
    finally:
        _FOLDER = previous


class _Unknown(Exception):
    """A static part with no value-based description: the call is not cached."""


def _describe(x) -> str:
    """A description of a static (non-array) part by value, the same in every process;
    raises `_Unknown` where there is none."""
    if x is None or isinstance(x, (bool, int, float, complex, str, bytes)):
        return repr(x)
    if isinstance(x, enum.Enum):
        return f"{type(x).__module__}.{type(x).__qualname__}.{x.name}"
    if isinstance(x, (tuple, list)):
        inner = ",".join(_describe(v) for v in x)
        return f"{type(x).__name__}({inner})"
    if isinstance(x, dict):
        items = sorted((_describe(k), _describe(v)) for k, v in x.items())
        return "dict(" + ",".join(f"{k}:{v}" for k, v in items) + ")"
    if isinstance(x, frozenset):
        return "frozenset(" + ",".join(sorted(_describe(v) for v in x)) + ")"
    if isinstance(x, (np.ndarray, np.generic)):
        a = np.asarray(x)
        digest = hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()
        return f"ndarray({a.dtype},{a.shape},{digest})"
    if isinstance(x, np.dtype):
        return f"dtype({x})"
    if isinstance(x, (types.FunctionType, types.BuiltinFunctionType, type)):
        return _named(x)
    if isinstance(x, functools.partial):
        return (
            f"partial({_describe(x.func)},{_describe(x.args)},{_describe(x.keywords)})"
        )
    if isinstance(x, jax.sharding.Mesh):
        ids = np.vectorize(lambda d: d.id)(x.devices)
        return f"Mesh({x.axis_names},{ids.tolist()})"
    if isinstance(x, eqx.Module) or dataclasses.is_dataclass(x):
        fields = ",".join(
            f"{f.name}={_describe(getattr(x, f.name, None))}"
            for f in dataclasses.fields(x)
        )
        return f"{_named(type(x))}({fields})"
    raise _Unknown(type(x).__qualname__)


def _named(x) -> str:
    module = getattr(x, "__module__", None) or ""
    name = getattr(x, "__qualname__", None) or ""
    if module.split(".")[0] not in _KNOWN_MODULES:
        raise _Unknown(repr(x))  # code the key does not cover
    if not name or "<locals>" in name or "<lambda>" in name:
        raise _Unknown(repr(x))  # a closure: its captured values are not in its name
    return f"{module}.{name}"


def _sharding(a):
    """An input's placement over a mesh, or None for one on a single device (which jit
    moves where the others are, as it moves a NumPy array)."""
    sharding = getattr(a, "sharding", None)
    return sharding if isinstance(sharding, jax.sharding.NamedSharding) else None


def _placement(a) -> str:
    sharding = _sharding(a)
    if sharding is None:
        return "one device"
    return f"named({_describe(sharding.mesh)},{sharding.spec})"


@functools.cache
def _environment() -> str:
    """What every key shares: the libraries' versions, jaxmr's source, the platform
    and devices, and the configuration that changes how JAX traces."""
    digest = hashlib.sha256()
    root = Path(__file__).resolve().parent
    for path in sorted(root.rglob("*.py")):
        digest.update(str(path.relative_to(root)).encode())
        digest.update(path.read_bytes())
    versions = []
    for name in _LIBRARIES:
        try:
            versions.append(f"{name}={importlib.metadata.version(name)}")
        except importlib.metadata.PackageNotFoundError:
            versions.append(f"{name}=none")
    config = [
        f"{name}={getattr(jax.config, name, None)}"
        for name in (
            "jax_enable_x64",
            "jax_default_matmul_precision",
            "jax_numpy_rank_promotion",
            "jax_numpy_dtype_promotion",
            "jax_default_prng_impl",
        )
    ]
    devices = [f"{d.platform}:{d.id}" for d in jax.devices()]
    return ";".join([digest.hexdigest(), *versions, *config, *devices])


def _key(name: str, leaves, static) -> str:
    parts = [
        _environment(),
        name,
        _describe(static),
        *(
            f"{np.dtype(a.dtype)}{tuple(a.shape)}{getattr(a, 'weak_type', False)}"
            f"{_placement(a)}"
            for a in leaves
        ),
    ]
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()


def cached(out_like: Callable) -> Callable:
    """A decorator: `eqx.filter_jit(fn)`, whose program is kept on disk
    (`traced_programs_in`) and read back by a later process with the same static
    arguments and input shapes.

    `fn` returns a pytree of arrays whose structure `out_like(*args)` gives (any
    pytree of that structure): a process that reads the program back does not trace
    `fn`, and so cannot learn it.
    """

    def decorator(fn: Callable) -> Callable:
        jitted = eqx.filter_jit(fn)
        name = f"{fn.__module__}.{fn.__qualname__}"

        @functools.wraps(fn)
        def call(*args, **kwargs):
            if _FOLDER is None or kwargs or jax.process_count() > 1:
                return jitted(*args, **kwargs)
            dynamic, static = eqx.partition(args, eqx.is_array)
            leaves, treedef = jax.tree.flatten(dynamic)
            try:
                key = _key(name, leaves, (static, str(treedef)))
            except _Unknown:
                return jitted(*args)
            if key in _MEMORY:
                exported = _MEMORY[key]
            else:
                exported = _load(key)
                if exported is None:
                    exported = _export(jitted, static, treedef, leaves, key)
                _MEMORY[key] = exported
            if exported is None:
                return jitted(*args)
            out = exported.call(*leaves)
            return jax.tree.unflatten(jax.tree.structure(out_like(*args)), out)

        return call

    return decorator


def _export(jitted, static, treedef, leaves, key):
    """`jitted` on these arguments exported and written to the folder, or None where
    JAX cannot export it (then the call is traced as usual in this process)."""

    def flat(*arrays):
        args = eqx.combine(jax.tree.unflatten(treedef, arrays), static)
        out = jitted(*args)
        return jax.tree.leaves(out)

    specs = [
        jax.ShapeDtypeStruct(a.shape, a.dtype, sharding=_sharding(a)) for a in leaves
    ]
    try:
        exported = jax.export.export(jax.jit(flat))(*specs)
        blob = exported.serialize()
    except Exception:  # noqa: BLE001 - what JAX cannot export is traced as usual
        return None
    _write(key, blob)
    return exported


def _path(key: str) -> Path:
    assert _FOLDER is not None
    return _FOLDER / f"{key}.jaxexport"


def _load(key: str):
    if _FOLDER is None:
        return None
    try:
        blob = _path(key).read_bytes()
    except OSError:
        return None
    try:
        return jax.export.deserialize(bytearray(blob))
    except Exception:  # noqa: BLE001 - unreadable: traced again and written over
        return None


def _write(key: str, blob: bytes | bytearray) -> None:
    """Written whole or not at all (`write_atomically`): a process reading the folder
    meanwhile sees no file or the whole one."""
    assert _FOLDER is not None
    try:
        _FOLDER.mkdir(parents=True, exist_ok=True)
        write_atomically(_path(key), lambda path: path.write_bytes(blob))
    except OSError:
        pass  # a read-only or full disk: the program is traced again next time
