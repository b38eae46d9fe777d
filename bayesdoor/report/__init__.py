"""Figures and summaries at the edge of the library, shared by the command-line tools."""

from ._calibration import plot_reliability as plot_reliability
from ._damage import bands_figure as bands_figure
from ._damage import confusion_figure as confusion_figure
from ._damage import probability_bars as probability_bars
from ._damage import uncertainty_figure as uncertainty_figure
from ._damage import write_damage_report as write_damage_report
from ._diagnosis import cause_figures as cause_figures
from ._diagnosis import coherence_figure as coherence_figure
from ._diagnosis import diagnosis_page as diagnosis_page
from ._diagnosis import diagnosis_section as diagnosis_section
from ._diagnosis import excess_figure as excess_figure
from ._diagnosis import parameter_text as parameter_text
from ._diagnosis import residual_map_figure as residual_map_figure
from ._diagnosis import rest_figure as rest_figure
from ._diagnosis import speed_figure as speed_figure
from ._diagnosis import write_diagnosis_report as write_diagnosis_report
from ._posterior import ablation_table as ablation_table
from ._posterior import plot_posterior_pairs as plot_posterior_pairs
from ._posterior import plot_posterior_trace as plot_posterior_trace
from ._posterior import plot_predictive_bands as plot_predictive_bands
from ._psd import STATE_COLORS as STATE_COLORS
from ._psd import RunPSDs as RunPSDs
from ._psd import campaign_psds as campaign_psds
from ._psd import motion_windows as motion_windows
from ._psd import plot_state_psds as plot_state_psds
from ._psd import segments_in_window as segments_in_window
