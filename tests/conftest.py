"""Tests run in float64 with strict dtype promotion: identification and the tolerances
stated in the tests need double precision, and strict promotion catches silent
float32/int mixing in the models."""

import jax

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")


# Longest first: the notebooks take minutes each, so under `pytest -n 2` they start at
# once on the two workers and the short tests fill in around them (collected last,
# the 3-minute identification notebook made one worker run on alone at the end).
_SLOW_FIRST = ("02_", "04_", "01_", "03_", "05_")


def pytest_collection_modifyitems(config, items):
    def rank(item):
        if "test_notebooks" not in item.nodeid:
            return len(_SLOW_FIRST) + 1
        for k, prefix in enumerate(_SLOW_FIRST):
            if prefix in item.nodeid:
                return k
        return len(_SLOW_FIRST)

    items.sort(key=rank)  # stable: the rest keep their order
