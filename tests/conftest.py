import os
import tempfile

import jax

# float64 is the project's default precision; the library never switches it on by itself.
jax.config.update("jax_enable_x64", True)

# The command lines keep a compile cache in the user's cache folder (cardiosoft._cli); the CLIs
# that tests launch share one of their own instead, never the user's. Set at import, before any
# test launches a process; a folder per session, left to the system's temporary-file cleanup.
os.environ["CARDIOSOFT_COMPILE_CACHE"] = tempfile.mkdtemp(prefix="cardiosoft-test-cache-")
