"""Uncertainty-aware classification: an Equinox CNN ensemble, calibration, metrics, OOD flag,
selective classification and the ensemble weighed against a physical signature check.

Generic over the system: inputs are arrays ``(sample, channel, freq)`` with integer labels and
class names.
"""

from ._calibration import TEMPERATURE_BOUNDS as TEMPERATURE_BOUNDS
from ._calibration import ensemble_nll as ensemble_nll
from ._calibration import fit_temperature as fit_temperature
from ._calibration import tempered_log_probabilities as tempered_log_probabilities
from ._config import TrainConfig as TrainConfig
from ._ensemble import Ensemble as Ensemble
from ._ensemble import Prediction as Prediction
from ._ensemble import predict as predict
from ._evidence import Evidence as Evidence
from ._evidence import combine_evidence as combine_evidence
from ._fit import FitOptions as FitOptions
from ._fit import calibrate as calibrate
from ._fit import fit_classifier as fit_classifier
from ._fit import fit_ood as fit_ood
from ._metrics import Binning as Binning
from ._metrics import ReliabilityBins as ReliabilityBins
from ._metrics import accuracy as accuracy
from ._metrics import brier_score as brier_score
from ._metrics import classification_metrics as classification_metrics
from ._metrics import confusion_matrix as confusion_matrix
from ._metrics import expected_calibration_error as expected_calibration_error
from ._metrics import negative_log_likelihood as negative_log_likelihood
from ._metrics import reliability_bins as reliability_bins
from ._network import ConvNet as ConvNet
from ._network import NetworkConfig as NetworkConfig
from ._network import parameter_count as parameter_count
from ._ood import MahalanobisOOD as MahalanobisOOD
from ._ood import fit_mahalanobis as fit_mahalanobis
from ._ood import ledoit_wolf as ledoit_wolf
from ._selective import SELECTIVE_RISK as SELECTIVE_RISK
from ._selective import RiskCoverage as RiskCoverage
from ._selective import Selection as Selection
from ._selective import risk_coverage as risk_coverage
from ._selective import risk_upper_bound as risk_upper_bound
from ._selective import select_calls as select_calls
from ._serialise import FORMAT_VERSION as FORMAT_VERSION
from ._serialise import load_ensemble as load_ensemble
from ._serialise import read_header as read_header
from ._serialise import save_ensemble as save_ensemble
from ._train import Training as Training
from ._train import train_ensemble as train_ensemble
from ._uncertainty import entropy as entropy
from ._uncertainty import expected_entropy as expected_entropy
from ._uncertainty import mutual_information as mutual_information
from ._uncertainty import predictive_entropy as predictive_entropy
