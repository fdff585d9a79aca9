"""cardiosoft: a differentiable lumped-parameter model of a cable-driven soft pump used as an
artificial heart ventricle (after "Harnessing Mechanical Instabilities in the Development of an
Efficient Soft Pump for an Artificial Heart Ventricle Simulator").

SI units inside (m, m^3, Pa, N, s); see :mod:`cardiosoft.units` for conversions. float64 is
recommended (switch on JAX's 64-bit mode in your script, as the README shows) and is what the
CLIs, notebooks and tests use; the library never switches it on by itself.

The public names below are imported on first use, so that ``python -m cardiosoft.<module>`` runs
a module that the package itself has not imported yet, and ``import cardiosoft`` stays cheap.
"""

import importlib

__version__ = "0.1.0"

_EXPORTS = {
    "units": "cardiosoft.units",
    "Shell": "cardiosoft.geometry",
    "apex_motion": "cardiosoft.geometry",
    "cavity_volume": "cardiosoft.geometry",
    "PumpSurrogate": "cardiosoft.pump",
    "load_pump": "cardiosoft.pump",
    "load_scene": "cardiosoft.scene",
    "run": "cardiosoft.experiment",
    "sweep": "cardiosoft.experiment",
}
_RENAMED = {"load_pump": "load"}

__all__ = sorted(_EXPORTS)


def __getattr__(name):
    if name in _EXPORTS:
        module = importlib.import_module(_EXPORTS[name])
        value = (module if module.__name__.endswith(name)
                 else getattr(module, _RENAMED.get(name, name)))
        globals()[name] = value
        return value
    raise AttributeError(f"module 'cardiosoft' has no attribute {name!r}")


def __dir__():
    return sorted([*globals(), *_EXPORTS])
