"""Spectral features in JAX: Welch PSD and its scatter, log bands, the CNN input, the objective J,
motion window."""

from ._motion import MotionDetection as MotionDetection
from ._motion import motion_window as motion_window
from ._spectra import LOG_FLOOR as LOG_FLOOR
from ._spectra import CNNInputSpec as CNNInputSpec
from ._spectra import band_envelope as band_envelope
from ._spectra import band_features as band_features
from ._spectra import cnn_input as cnn_input
from ._spectra import log_psd as log_psd
from ._spectra import objective_j as objective_j
from ._welch import WelchOptions as WelchOptions
from ._welch import segment_weights as segment_weights
from ._welch import welch_csd as welch_csd
from ._welch import welch_psd as welch_psd
from ._welch import welch_segment_count as welch_segment_count
from ._welch_stats import dof_from_log10_variance as dof_from_log10_variance
from ._welch_stats import log10_psd_variance as log10_psd_variance
from ._welch_stats import log_chi2_normal_scores as log_chi2_normal_scores
from ._welch_stats import welch_dof as welch_dof
from ._welch_stats import windowed_log_psd as windowed_log_psd
