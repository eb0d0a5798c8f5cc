"""Fixtures of the service tests; defined in :mod:`svc_helpers` (a uniquely named module the tests import helpers from)."""

from svc_helpers import client, populated, scene  # noqa: F401
