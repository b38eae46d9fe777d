"""Discrepancy diagnosis: where the model departs from measurements, and which cause fits.

The layer is generic: a system supplies its catalogue of candidate causes as data
(:class:`Catalogue` of :class:`Candidate` with signatures), the diagnosis finds the residual
features and ranks the candidates.

The public names are what a user calls:

- running a diagnosis and reading its result: :func:`diagnose_campaign` with
  :class:`DiagnosisSettings` gives a :class:`Diagnosis`: each candidate as a :class:`Cause`
  with its held-out :class:`Gain`, each pair of confirmed causes judged against each other
  (:class:`Contest`), the signature :class:`Ranking` (:class:`CauseScore` per
  candidate) on the residual :class:`Features`; :func:`verdict_extension` and
  :func:`extend_system` (:class:`HeldExtension`) carry the verdict to the system;
- the residual features and the pieces the user guide (``docs/diagnosis.md``) documents for
  use alone: :func:`find_features`, :func:`rank_causes`, :func:`residual_map`,
  :func:`coherence_map`, :func:`rest_lines`, :func:`windowed_log_psd`, :func:`welch_dof`,
  :func:`log10_psd_variance`, and the types they return;
- what a system's catalogue of causes is built from: :class:`Catalogue`, :class:`Candidate`,
  the signatures (:class:`AbstractSignature`, whose ``match`` returns a :class:`Match` of
  :class:`Check` results, and the concrete ones) and the refit recipes
  (:class:`AbstractRefit`, whose ``propose`` returns :class:`ExtensionProposal` objects;
  ``LOCAL_BINS``, the main lobe of the spectra a recipe's ``explains`` reads);
- the decision rule: ``RULE`` in words, :func:`rule_thresholds`, :func:`rule_passes` and the
  capped statistic :func:`capped_t`;
- what a campaign could not have shown: each cause's size (:class:`CauseSize` of
  :class:`SizeProbe` configurations, declared by its recipe's ``size``) and its
  :class:`CauseLimit` (:class:`PowerCurve` per configuration) from :func:`detection_limits`
  at the power :data:`LIMIT_POWER`; how a family of machines transmits a cause against the
  model (:class:`Transmission`, read per machine by :func:`read_transmission` as a
  :class:`TransmissionReading`), which turns a model limit into a family limit;
  :func:`plan_campaign` (a :class:`CampaignPlan`): the campaign that would name a cause of a
  given size.

The tuning constants and the internal steps stay in their private modules.
"""

from ..features import log10_psd_variance as log10_psd_variance
from ..features import welch_dof as welch_dof
from ..features import windowed_log_psd as windowed_log_psd
from ._coherence import CoherenceMap as CoherenceMap
from ._coherence import PairCoherence as PairCoherence
from ._coherence import coherence_map as coherence_map
from ._design import CampaignPlan as CampaignPlan
from ._diagnosis import Cause as Cause
from ._diagnosis import Diagnosis as Diagnosis
from ._diagnosis import DiagnosisSettings as DiagnosisSettings
from ._extend import HeldExtension as HeldExtension
from ._extend import VerdictExtension as VerdictExtension
from ._extend import extend_system as extend_system
from ._extend import verdict_extension as verdict_extension
from ._features import Features as Features
from ._features import FeatureSettings as FeatureSettings
from ._features import RunMotion as RunMotion
from ._features import find_features as find_features
from ._gain import LOCAL_BINS as LOCAL_BINS
from ._gain import RULE as RULE
from ._gain import Contest as Contest
from ._gain import Discrepancy as Discrepancy
from ._gain import Gain as Gain
from ._gain import capped_t as capped_t
from ._gain import rule_passes as rule_passes
from ._gain import rule_thresholds as rule_thresholds
from ._job import diagnose_campaign as diagnose_campaign
from ._limits import LIMIT_POWER as LIMIT_POWER
from ._limits import CauseLimit as CauseLimit
from ._limits import PowerCurve as PowerCurve
from ._limits import TransmissionReading as TransmissionReading
from ._limits import detection_limits as detection_limits
from ._limits import read_transmission as read_transmission
from ._order import OrderSpectra as OrderSpectra
from ._plan import PlanSettings as PlanSettings
from ._plan import plan_campaign as plan_campaign
from ._rank import NONE as NONE
from ._rank import Candidate as Candidate
from ._rank import Catalogue as Catalogue
from ._rank import CauseScore as CauseScore
from ._rank import Ranking as Ranking
from ._rank import rank_causes as rank_causes
from ._refit import AbstractRefit as AbstractRefit
from ._refit import CauseSize as CauseSize
from ._refit import ExtensionProposal as ExtensionProposal
from ._refit import SizeProbe as SizeProbe
from ._refit import Symptom as Symptom
from ._residual import Region as Region
from ._residual import ResidualMap as ResidualMap
from ._residual import ResidualSettings as ResidualSettings
from ._residual import RunPeaks as RunPeaks
from ._residual import SpeedFit as SpeedFit
from ._residual import residual_map as residual_map
from ._rest import LineAtRest as LineAtRest
from ._rest import RestLines as RestLines
from ._rest import rest_lines as rest_lines
from ._signatures import AbstractSignature as AbstractSignature
from ._signatures import Check as Check
from ._signatures import CrossAxisCoherence as CrossAxisCoherence
from ._signatures import FirstOf as FirstOf
from ._signatures import FixedFrequency as FixedFrequency
from ._signatures import HarmonicComb as HarmonicComb
from ._signatures import ListedFrequency as ListedFrequency
from ._signatures import Match as Match
from ._signatures import NoResidual as NoResidual
from ._signatures import RestLine as RestLine
from ._signatures import SpeedTracking as SpeedTracking
from ._transmission import Transmission as Transmission
from ._within import WithinRunFit as WithinRunFit
