"""Feature matching for loop/revisit verification: XFeat (ONNX) or ORB, mutual NN, PnP-RANSAC gate."""

from models.matcher.features import Features, Matches, mutual_nearest_neighbours
from models.matcher.lighterglue import LighterGlue
from models.matcher.matcher import Matcher
from models.matcher.pnp import PnPGates, PnPResult, verify_pnp
from models.matcher.refine import refine_matches_lk
from models.matcher.xfeat import DEFAULT_XFEAT_PATH, XFeatDetector

__all__ = [
    "DEFAULT_XFEAT_PATH",
    "Features",
    "LighterGlue",
    "Matcher",
    "Matches",
    "PnPGates",
    "PnPResult",
    "XFeatDetector",
    "mutual_nearest_neighbours",
    "refine_matches_lk",
    "verify_pnp",
]
