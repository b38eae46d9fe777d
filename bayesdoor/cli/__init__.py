"""The ``bayesdoor`` command line."""

from ._app import app as app
