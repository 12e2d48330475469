"""Fixtures for tests/planning: the ellipsoid world of tests/eval_world.py (recorded views with cameras)."""

from eval_world import sphere_world  # noqa: F401
