"""Campaign files at the edge of the library: NetCDF through xarray."""

from ._campaign import load_campaign as load_campaign
from ._campaign import make_campaign as make_campaign
from ._campaign import save_campaign as save_campaign
