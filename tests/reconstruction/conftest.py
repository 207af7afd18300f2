"""Fixtures shared with the factory's tests: the session's short shirt walk (a real simulation),
from which tests make a tiny real capture."""

from tests.factory.conftest import shirt_run

__all__ = ["shirt_run"]  # a pytest fixture, found by name
