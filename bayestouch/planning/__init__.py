"""Active probing: candidate strokes, expected information gain, policies, the exploration loop and the
experiment runner (issue 5). See :mod:`bayestouch.planning.signal` for the contact-level stroke
signal."""

# ray_distances and true_ray_distances live in geometry.nellipsoid and scene.raycast; re-exported here as before
from bayestouch.geometry.nellipsoid import ray_distances
from bayestouch.planning.candidates import Strokes, make_candidates, select
from bayestouch.planning.eig import decide, eig_gaussian, eig_pce, eig_per_point
from bayestouch.planning.loop import ExploreSettings, explore
from bayestouch.planning.policies import POLICIES, choose
from bayestouch.planning.signal import predict_signals
from bayestouch.scene.raycast import true_ray_distances

__all__ = [
    "Strokes",
    "make_candidates",
    "select",
    "decide",
    "eig_gaussian",
    "eig_pce",
    "eig_per_point",
    "ExploreSettings",
    "explore",
    "POLICIES",
    "choose",
    "predict_signals",
    "ray_distances",
    "true_ray_distances",
]
