import os
import random
import tempfile

import jax
from hypothesis import settings

# float64 is the project's default precision; the library never switches it on by itself.
jax.config.update("jax_enable_x64", True)

# The command lines keep a compile cache in the user's cache folder (cardiosoft._cli); the CLIs
# that tests launch share one of their own instead, never the user's. Set at import, before any
# test launches a process; a folder per session, left to the system's temporary-file cleanup.
os.environ["CARDIOSOFT_COMPILE_CACHE"] = tempfile.mkdtemp(prefix="cardiosoft-test-cache-")

# Hypothesis profiles (tests/README.md, "Property tests"):
# - "ci": derandomized (each test draws the same examples on every run and every machine) and
#   no example database (nothing carried over from an earlier run): what `-m "not slow"` runs;
# - "random": fresh draws each run, from a seed printed in pytest's header; chosen by
#   CARDIOSOFT_HYPOTHESIS_PROFILE=random, or by a run that selects the slow tests (`-m slow`).
#   CARDIOSOFT_HYPOTHESIS_SEED=N (or --hypothesis-seed=N) repeats the draws of seed N.
# Loaded at import, so that the @settings of the test modules inherit from it.
PROFILE_VARIABLE, SEED_VARIABLE = "CARDIOSOFT_HYPOTHESIS_PROFILE", "CARDIOSOFT_HYPOTHESIS_SEED"
settings.register_profile("ci", derandomize=True, database=None, deadline=None, print_blob=True)
settings.register_profile(
    "random", derandomize=False, database=None, deadline=None, print_blob=True, max_examples=200
)
settings.load_profile("ci")


def _profile(config) -> str:
    name = os.environ.get(PROFILE_VARIABLE)
    if name:
        return name
    marks = config.getoption("markexpr") or ""
    return "random" if "slow" in marks and "not slow" not in marks else "ci"


def pytest_configure(config):
    name = _profile(config)
    settings.load_profile(name)  # an unknown name raises, naming the registered ones
    if name == "random" and config.getoption("hypothesis_seed") is None:
        # read by hypothesis's own pytest plugin, whose configure hook runs after this one
        config.option.hypothesis_seed = os.environ.get(SEED_VARIABLE) or str(
            random.SystemRandom().getrandbits(32)
        )


def pytest_report_header(config):
    name = settings.get_current_profile_name()
    if settings.default.derandomize:
        return f"hypothesis profile {name!r}: derandomized (the same draws on every run)"
    seed = config.getoption("hypothesis_seed")
    return f"hypothesis profile {name!r}: seed {seed} (repeat with {SEED_VARIABLE}={seed})"
