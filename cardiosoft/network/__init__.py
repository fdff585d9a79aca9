"""Networks of blocks, and svZeroDSolver's models read into them.

``read`` takes an svZeroDSolver JSON model (a path or a dict), ``simulate`` runs it as
svZeroDSolver defines the run and returns its variables under svZeroDSolver's names (the
model's converged answer); ``step_as_svzerod`` steps it as svZeroDSolver steps it (its
digits).
svZeroDSolver files carry no units: a model is solved in its own (CGS, mmHg-ml-s or SI).
"""

from typing import TYPE_CHECKING

from cardiosoft.lazy import on_first_use

PUBLIC = {
    "Network": "cardiosoft.network.network",
    "Traces": "cardiosoft.network.run",
    "simulate": "cardiosoft.network.run",
    "UnsupportedModel": "cardiosoft.network.simulation_parameters",
    "SUPPORTED_BLOCKS": "cardiosoft.network.svzerod",
    "Model": "cardiosoft.network.svzerod",
    "read": "cardiosoft.network.svzerod",
    "run_svzerod": "cardiosoft.network.svzerod",
    "step_as_svzerod": "cardiosoft.network.gen_alpha",
}
"""Each public name and the module it is defined in, imported on first use: a scene's modules
import this package's blocks without its svZeroDSolver reader."""

__all__ = [
    "SUPPORTED_BLOCKS", "Model", "Network", "Traces", "UnsupportedModel", "read", "run_svzerod",
    "simulate", "step_as_svzerod",
]  # fmt: skip

if TYPE_CHECKING:  # what type checkers read; at run time __getattr__ imports these
    from cardiosoft.network.gen_alpha import step_as_svzerod as step_as_svzerod
    from cardiosoft.network.network import Network as Network
    from cardiosoft.network.run import Traces as Traces
    from cardiosoft.network.run import simulate as simulate
    from cardiosoft.network.simulation_parameters import UnsupportedModel as UnsupportedModel
    from cardiosoft.network.svzerod import SUPPORTED_BLOCKS as SUPPORTED_BLOCKS
    from cardiosoft.network.svzerod import Model as Model
    from cardiosoft.network.svzerod import read as read
    from cardiosoft.network.svzerod import run_svzerod as run_svzerod


__getattr__, __dir__ = on_first_use(globals(), PUBLIC)
