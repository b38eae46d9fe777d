"""Generic optimisation and sampling: CMA-ES, NUTS and emcee posteriors, diagnostics gates."""

from ._cmaes import CMAESHistory as CMAESHistory
from ._cmaes import CMAESResult as CMAESResult
from ._cmaes import cmaes_options as cmaes_options
from ._cmaes import minimize_cmaes as minimize_cmaes
from ._cmaes import plot_cmaes_history as plot_cmaes_history
from ._diagnostics import SamplingDiagnostics as SamplingDiagnostics
from ._diagnostics import SamplingGateWarning as SamplingGateWarning
from ._diagnostics import diagnose_sampling as diagnose_sampling
from ._diagnostics import summary_table as summary_table
from ._posterior import POSTERIOR_GROUPS as POSTERIOR_GROUPS
from ._posterior import configuration_hash as configuration_hash
from ._posterior import load_posterior as load_posterior
from ._posterior import save_posterior as save_posterior
from ._samplers import sample_emcee as sample_emcee
from ._samplers import sample_nuts as sample_nuts
