"""Stereo visual odometry: the drone's own pose from its cameras, frame by frame."""

from skyrecon.odometry.types import FrameEstimate, TrackingState

__all__ = ["FrameEstimate", "TrackingState"]
