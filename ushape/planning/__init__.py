"""Next-best-view planning: let the fused uncertainty choose where to look next (see loop.py)."""

from ushape.planning.candidates import CandidateViews, candidate_views, orbit_views, recorded_views
from ushape.planning.loop import PlanState, Step, Surface, ViewEncoder, active_reconstruction, surface_of
from ushape.planning.strategies import STRATEGIES, build_strategy

__all__ = [
    "STRATEGIES",
    "CandidateViews",
    "PlanState",
    "Step",
    "Surface",
    "ViewEncoder",
    "active_reconstruction",
    "build_strategy",
    "candidate_views",
    "orbit_views",
    "recorded_views",
    "surface_of",
]
