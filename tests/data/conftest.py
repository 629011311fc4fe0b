"""Fixtures of the data tests."""

from tests.tasks.fakes import fake_data  # noqa: F401  (shared fixture)
