"""Simulated training data for the classifier: parameter sources, features, chunked generation."""

from ._adequacy import Adequacy as Adequacy
from ._adequacy import AdequacyCheck as AdequacyCheck
from ._adequacy import fit_adequacy as fit_adequacy
from ._adequacy import healthy_outliers as healthy_outliers
from ._config import GenerationConfig as GenerationConfig
from ._features import campaign_features as campaign_features
from ._features import featurize as featurize
from ._features import measured_features as measured_features
from ._features import measured_windows as measured_windows
from ._generate import FORMAT as FORMAT
from ._generate import Execution as Execution
from ._generate import TrainingData as TrainingData
from ._generate import describe_system as describe_system
from ._generate import generate as generate
from ._generate import load_training_data as load_training_data
from ._model_error import DISCREPANCY_FORM as DISCREPANCY_FORM
from ._model_error import calibration_residuals as calibration_residuals
from ._model_error import measurement_variance as measurement_variance
from ._model_error import model_error_draws as model_error_draws
from ._model_error import with_measured_discrepancy as with_measured_discrepancy
from ._sources import AbstractParameterSource as AbstractParameterSource
from ._sources import GaussianScatter as GaussianScatter
from ._sources import ModelErrorDraws as ModelErrorDraws
from ._sources import PosteriorDraws as PosteriorDraws
