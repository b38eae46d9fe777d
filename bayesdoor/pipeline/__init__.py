"""The main job over any system: fit, generate, train, classify and report, stage by stage."""

from ._bands import PredictiveBands as PredictiveBands
from ._classify import classify_stage as classify_stage
from ._classify import model_file as model_file
from ._classify import report_stage as report_stage
from ._classify import train_stage as train_stage
from ._fit import FitSummary as FitSummary
from ._job import SOURCES as SOURCES
from ._job import STAGES as STAGES
from ._job import Generation as Generation
from ._job import JobResult as JobResult
from ._job import Sizes as Sizes
from ._job import Source as Source
from ._job import calibration_runs as calibration_runs
from ._job import digest_runs as digest_runs
from ._job import generation_settings as generation_settings
from ._job import parameter_source as parameter_source
from ._job import run_job as run_job
from ._job import runs_to_classify as runs_to_classify
from ._stages import StageRecord as StageRecord
from ._stages import configuration_hash as configuration_hash
from ._stages import run_stage as run_stage
