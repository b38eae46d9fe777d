"""Generic optimisation and sampling: CMA-ES, NUTS and emcee posteriors, diagnostics gates."""

from ._cmaes import CMAESHistory as CMAESHistory
from ._cmaes import CMAESResult as CMAESResult
from ._cmaes import cmaes_options as cmaes_options
from ._cmaes import minimize_cmaes as minimize_cmaes
from ._cmaes import plot_cmaes_history as plot_cmaes_history
