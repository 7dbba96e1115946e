"""JAX set-up shared by the macro layer.

Imported first by every module that builds JAX arrays: orientation tensors are
integrated to rtol ~1e-8 and fitted to ~1e-6, which float32 cannot carry, so
64-bit mode is switched on before any array exists (JAX silently truncates to
float32 otherwise).
"""
import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402  (must follow the x64 switch)

__all__ = ["jax", "jnp"]
