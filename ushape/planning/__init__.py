"""Next-best-view planning: let the fused uncertainty choose where to look next (see loop.py)."""

from ushape.planning.candidates import CandidateViews, candidate_views, orbit_views, recorded_views
from ushape.planning.loop import PlanState, Step, Surface, ViewEncoder, active_reconstruction, surface_of
from ushape.planning.plugins import SequenceContext, build_observer, build_strategy

__all__ = [
    "CandidateViews",
    "PlanState",
    "SequenceContext",
    "Step",
    "Surface",
    "ViewEncoder",
    "active_reconstruction",
    "build_observer",
    "build_strategy",
    "candidate_views",
    "orbit_views",
    "recorded_views",
    "surface_of",
]
