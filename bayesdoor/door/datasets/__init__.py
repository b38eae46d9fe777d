"""Datasets shipped with bayesdoor: the demo campaign recorded by the virtual rig."""

from ._demo import DEMO as DEMO
from ._demo import cache_dir as cache_dir
from ._demo import demo_paths as demo_paths
from ._demo import load_demo_campaign as load_demo_campaign
from ._demo import load_demo_truth as load_demo_truth
