"""Campaign files at the edge of the library: NetCDF through xarray, CSV, validation."""

from ._campaign import load_campaign as load_campaign
from ._campaign import make_campaign as make_campaign
from ._campaign import save_campaign as save_campaign
from ._csv import SIDECAR as SIDECAR
from ._csv import from_csv as from_csv
from ._csv import to_csv as to_csv
from ._format import ACCELERATION_UNITS as ACCELERATION_UNITS
from ._format import CONVERTIBLE_UNITS as CONVERTIBLE_UNITS
from ._format import SPLIT_LABELS as SPLIT_LABELS
from ._format import SYSTEM_SETTINGS as SYSTEM_SETTINGS
from ._format import UNKNOWN as UNKNOWN
from ._format import atomic_write as atomic_write
from ._format import operating as operating
from ._format import state_labels as state_labels
from ._format import system_of as system_of
from ._format import with_campaign_settings as with_campaign_settings
from ._validate import CampaignError as CampaignError
from ._validate import Problem as Problem
from ._validate import check_campaign as check_campaign
from ._validate import validate_campaign as validate_campaign
