"""Networks of blocks, and svZeroDSolver's models read into them.

``read`` takes an svZeroDSolver JSON model (a path or a dict), ``simulate`` runs it as
svZeroDSolver defines the run and returns its variables under svZeroDSolver's names.
svZeroDSolver files carry no units: a model is solved in its own (CGS, mmHg-ml-s or SI).
"""

from cardiosoft.network.network import Network as Network
from cardiosoft.network.run import Traces as Traces
from cardiosoft.network.run import simulate as simulate
from cardiosoft.network.simulation_parameters import UnsupportedModel as UnsupportedModel
from cardiosoft.network.svzerod import SUPPORTED_BLOCKS as SUPPORTED_BLOCKS
from cardiosoft.network.svzerod import Model as Model
from cardiosoft.network.svzerod import read as read
from cardiosoft.network.svzerod import run_svzerod as run_svzerod
