"""Command-line options that name the topics of a ROS bag / MCAP input (``map``, ``odometry``, ``stereo``)."""

from __future__ import annotations

import argparse

from skyrecon.cli.common import positive_float
from skyrecon.io.rosbag_input import BagTopics

__all__ = ["add_bag_options", "bag_topics"]


def add_bag_options(parser: argparse.ArgumentParser) -> None:
    """``--left-topic``, ``--right-topic``, ``--left-info-topic``, ``--right-info-topic``,
    ``--pose-topic`` and ``--sync-tolerance``, grouped under "ROS bag / MCAP input"."""
    g = parser.add_argument_group(
        "ROS bag / MCAP input",
        "when the input is a ROS 2 bag directory, a ROS 1 .bag or an .mcap file (needs the 'ros' extra)",
    )
    g.add_argument(
        "--left-topic", metavar="TOPIC", help="left images (sensor_msgs/msg/Image or CompressedImage)"
    )
    g.add_argument("--right-topic", metavar="TOPIC", help="right images, paired with the left by stamp")
    g.add_argument(
        "--left-info-topic",
        metavar="TOPIC",
        help="left sensor_msgs/msg/CameraInfo (default: the image topic's namespace + /camera_info)",
    )
    g.add_argument("--right-info-topic", metavar="TOPIC", help="right CameraInfo (default as for the left)")
    g.add_argument(
        "--pose-topic",
        metavar="TOPIC",
        help="world_from_left camera poses (nav_msgs/msg/Odometry, geometry_msgs/msg/PoseStamped or "
        "TransformStamped), interpolated to image times",
    )
    g.add_argument(
        "--sync-tolerance",
        type=positive_float,
        default=5.0,
        metavar="MS",
        help="largest left/right stamp difference of a stereo pair, milliseconds (default 5)",
    )


def bag_topics(args: argparse.Namespace) -> BagTopics:
    """The :class:`BagTopics` the options name."""
    return BagTopics(
        left=args.left_topic,
        right=args.right_topic,
        left_info=args.left_info_topic,
        right_info=args.right_info_topic,
        pose=args.pose_topic,
        sync_tolerance_s=args.sync_tolerance / 1000.0,
    )
