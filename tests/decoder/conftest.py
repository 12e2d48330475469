"""Fixtures for tests/decoder: defined in sphere_world.py, a uniquely named module that test files import directly
(several conftest modules share the name `conftest`, so importing from it is order-dependent)."""

from sphere_world import *  # noqa: F401,F403
