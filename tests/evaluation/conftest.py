"""Fixtures for tests/evaluation: defined in eval_world.py, a uniquely named module that test files import directly
(several conftest modules share the name `conftest`, so importing from it is order-dependent)."""

from eval_world import *  # noqa: F401,F403
