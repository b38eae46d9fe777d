"""Spectral features in JAX: Welch PSD, log bands, the CNN input, the objective J, motion window."""

from ._motion import motion_window as motion_window
from ._spectra import LOG_FLOOR as LOG_FLOOR
from ._spectra import CNNInputSpec as CNNInputSpec
from ._spectra import band_features as band_features
from ._spectra import cnn_input as cnn_input
from ._spectra import log_psd as log_psd
from ._spectra import objective_j as objective_j
from ._welch import segment_weights as segment_weights
from ._welch import welch_psd as welch_psd
