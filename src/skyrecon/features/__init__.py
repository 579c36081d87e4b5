"""Feature detection (SIFT / RootSIFT / ORB / AKAZE) and descriptor matching (ratio + mutual)."""

from skyrecon.features.detect import (
    Features,
    FeatureSettings,
    detect_features,
    resize_longer_side,
    to_gray_uint8,
)
from skyrecon.features.match import Matches, MatchSettings, match_descriptors, match_features

__all__ = [
    "FeatureSettings",
    "Features",
    "detect_features",
    "resize_longer_side",
    "to_gray_uint8",
    "MatchSettings",
    "Matches",
    "match_descriptors",
    "match_features",
]
