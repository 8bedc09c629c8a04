"""Tests run in float64 with strict dtype promotion: identification and the tolerances
stated in the tests need double precision, and strict promotion catches silent
float32/int mixing in the models."""

import jax

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")
