"""XLA flags of the test session, in a module that imports nothing (tests/conftest.py
sets them before JAX starts its backend)."""

# Compile faster programs that run slower: tests/conftest.py sets them for the session,
# tests/test_notebooks.py takes them off for the notebooks' kernels.
FAST_COMPILE_FLAGS = (
    "--xla_backend_optimization_level=0",
    "--xla_llvm_disable_expensive_passes=true",
)
