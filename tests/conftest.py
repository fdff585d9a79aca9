import jax

# float64 is the project's default precision; the library never switches it on by itself.
jax.config.update("jax_enable_x64", True)
