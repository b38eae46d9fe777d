"""Discrepancy diagnosis: where the model departs from measurements, and which cause fits.

The layer is generic: a system supplies its catalogue of candidate causes as data
(:class:`Catalogue` of :class:`Candidate` with signatures), the diagnosis finds the residual
features and ranks the candidates.
"""

from ._coherence import CoherenceMap as CoherenceMap
from ._coherence import PairCoherence as PairCoherence
from ._coherence import coherence_map as coherence_map
from ._comb import CombTest as CombTest
from ._comb import harmonic_comb as harmonic_comb
from ._features import Features as Features
from ._features import find_features as find_features
from ._gain import CAPPED_THRESHOLDS as CAPPED_THRESHOLDS
from ._gain import CHANGE_FRACTION as CHANGE_FRACTION
from ._gain import DECISIVE_SE as DECISIVE_SE
from ._gain import LOCAL_BINS as LOCAL_BINS
from ._gain import RULE as RULE
from ._gain import SIGMA_FLOOR as SIGMA_FLOOR
from ._gain import UNION_SCALE as UNION_SCALE
from ._gain import ChangeDiscrepancy as ChangeDiscrepancy
from ._gain import Discrepancy as Discrepancy
from ._gain import Gain as Gain
from ._gain import TrackingChangeDiscrepancy as TrackingChangeDiscrepancy
from ._gain import capped_t as capped_t
from ._gain import capped_threshold as capped_threshold
from ._gain import changed_bins as changed_bins
from ._gain import compare_held_out as compare_held_out
from ._gain import estimate_change_discrepancy as estimate_change_discrepancy
from ._gain import estimate_discrepancy as estimate_discrepancy
from ._gain import estimate_tracking_change_discrepancy as estimate_tracking_change_discrepancy
from ._gain import feature_bins as feature_bins
from ._gain import log_predictive as log_predictive
from ._gain import rule_passes as rule_passes
from ._gain import rule_thresholds as rule_thresholds
from ._gain import t_statistic as t_statistic
from ._job import Cause as Cause
from ._job import Diagnosis as Diagnosis
from ._job import DiagnosisSettings as DiagnosisSettings
from ._job import base_fit_notes as base_fit_notes
from ._job import diagnose_campaign as diagnose_campaign
from ._job import extension_gain as extension_gain
from ._job import held_out_folds as held_out_folds
from ._job import judge_folds as judge_folds
from ._job import tracks_speed as tracks_speed
from ._job import verdict_order as verdict_order
from ._order import OrderSpectra as OrderSpectra
from ._order import order_log_psd as order_log_psd
from ._order import order_peak as order_peak
from ._rank import NONE as NONE
from ._rank import Candidate as Candidate
from ._rank import Catalogue as Catalogue
from ._rank import CauseScore as CauseScore
from ._rank import Ranking as Ranking
from ._rank import rank_causes as rank_causes
from ._refit import AbstractRefit as AbstractRefit
from ._refit import ExtensionProposal as ExtensionProposal
from ._refit import RefitResult as RefitResult
from ._refit import RefitSetup as RefitSetup
from ._refit import Spectra as Spectra
from ._refit import box_ends as box_ends
from ._refit import exact_spectra as exact_spectra
from ._refit import held_out_spectra as held_out_spectra
from ._refit import refit_extension as refit_extension
from ._residual import Region as Region
from ._residual import ResidualMap as ResidualMap
from ._residual import RunPeaks as RunPeaks
from ._residual import SpeedFit as SpeedFit
from ._residual import residual_map as residual_map
from ._residual import smooth_discrepancy as smooth_discrepancy
from ._rest import LineAtRest as LineAtRest
from ._rest import RestLines as RestLines
from ._rest import rest_lines as rest_lines
from ._rest import rest_segments as rest_segments
from ._signatures import AbstractSignature as AbstractSignature
from ._signatures import Check as Check
from ._signatures import CrossAxisCoherence as CrossAxisCoherence
from ._signatures import FirstOf as FirstOf
from ._signatures import FixedFrequency as FixedFrequency
from ._signatures import HarmonicComb as HarmonicComb
from ._signatures import Match as Match
from ._signatures import NoResidual as NoResidual
from ._signatures import RestLine as RestLine
from ._signatures import SpeedTracking as SpeedTracking
from ._stats import benjamini_hochberg as benjamini_hochberg
from ._welch_stats import dof_from_log10_variance as dof_from_log10_variance
from ._welch_stats import log10_psd_variance as log10_psd_variance
from ._welch_stats import log_chi2_normal_scores as log_chi2_normal_scores
from ._welch_stats import welch_dof as welch_dof
from ._welch_stats import windowed_log_psd as windowed_log_psd
from ._within import WithinRunFit as WithinRunFit
from ._within import within_run_speed as within_run_speed

# isort: split
# last: the extended systems subclass bayesdoor.systems.AbstractSystem, and importing
# bayesdoor.systems imports the door catalogue, which needs the names above
from ._extend import HeldExtension as HeldExtension
from ._extend import VerdictExtension as VerdictExtension
from ._extend import extend_system as extend_system
from ._extend import verdict_extension as verdict_extension
