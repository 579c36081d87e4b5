"""A tiny synthetic stereo flight written in the EuRoC / ASL layout, with real lens distortion and a
slightly non-parallel camera pair, so that readers and rectification are exercised end to end.

The drone moves along a street of a generated city (forward, climbing, yawing); both cameras are
rendered as ideal pinholes on a padded canvas and then distorted with known radial-tangential
coefficients (``cv2.undistortPoints`` of every distorted pixel gives where to sample the pinhole
render). Ground truth (``world_from_body`` at a higher rate than the cameras, at times that are not
the frame times) is written as ``state_groundtruth_estimate0/data.csv``.

Frames: world z up, metres; body x forward, y left, z up; cameras OpenCV axes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.rigid import Rigid3, matrix_to_quaternion, rotvec_to_matrix
from skyrecon.io.atomic import write_text_atomic
from skyrecon.io.images import to_gray, write_image
from skyrecon.sim.city import City
from skyrecon.sim.generate import generate_city
from skyrecon.sim.render import render
from skyrecon.sim.scenes import look_from, street_view_pose

__all__ = ["SyntheticEuroc", "write_synthetic_euroc", "EUROC_T0_NS"]

EUROC_T0_NS = 1403636579763555584  # the first stamp of EuRoC MH_01: realistic magnitudes
_BODY_FROM_CAM_AXES = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # cam z -> body x


@dataclass
class SyntheticEuroc:
    """What :func:`write_synthetic_euroc` wrote, with the truth.

    Attributes:
        root: the sequence directory (holding ``mav0/``).
        timestamps_ns: (N,) frame times.
        world_from_body: per-frame body poses, metres.
        body_from_cam0, body_from_cam1: the two cameras' extrinsics (``T_BS``).
        cam0, cam1: raw intrinsics with distortion.
        city: the scene.
    """

    root: Path
    timestamps_ns: np.ndarray
    world_from_body: list[Rigid3]
    body_from_cam0: Rigid3
    body_from_cam1: Rigid3
    cam0: Intrinsics
    cam1: Intrinsics
    city: City

    @property
    def world_from_cam0(self) -> list[Rigid3]:
        return [p @ self.body_from_cam0 for p in self.world_from_body]


def _sensor_yaml(intr: Intrinsics, body_from_cam: Rigid3, fps: float) -> str:
    rows = [", ".join(repr(float(v)) for v in row) for row in body_from_cam.matrix]
    data = ",\n         ".join(rows)  # one matrix row per line, as EuRoC writes it
    dist = ", ".join(repr(float(v)) for v in intr.dist[:4])
    return (
        "%YAML:1.0\n# General sensor definitions.\nsensor_type: camera\ncomment: skyrecon synthetic camera\n\n"
        "# Sensor extrinsics wrt. the body-frame.\nT_BS:\n  cols: 4\n  rows: 4\n"
        f"  data: [{data}]\n\n"
        f"rate_hz: {fps:g}\nresolution: [{intr.width}, {intr.height}]\ncamera_model: pinhole\n"
        f"intrinsics: [{intr.fx!r}, {intr.fy!r}, {intr.cx!r}, {intr.cy!r}] #fu, fv, cu, cv\n"
        f"distortion_model: radial-tangential\ndistortion_coefficients: [{dist}]\n"
    )


def _distorted_render(city: City, intr: Intrinsics, cam_from_world: Rigid3) -> np.ndarray:
    """(H, W, 3) uint8 RGB image of a camera with lens distortion ``intr.dist``."""
    pad = int(math.ceil(0.3 * max(intr.width, intr.height)))
    canvas = Intrinsics(
        intr.fx, intr.fy, intr.cx + pad, intr.cy + pad, intr.width + 2 * pad, intr.height + 2 * pad
    )
    ideal = render(city, canvas, cam_from_world).image
    u, v = np.meshgrid(np.arange(intr.width, dtype=np.float64), np.arange(intr.height, dtype=np.float64))
    pts = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
    xy = cv2.undistortPoints(pts, intr.K, intr.dist[:5]).reshape(-1, 2)  # normalised undistorted coords
    map_x = (canvas.fx * xy[:, 0] + canvas.cx).reshape(intr.height, intr.width).astype(np.float32)
    map_y = (canvas.fy * xy[:, 1] + canvas.cy).reshape(intr.height, intr.width).astype(np.float32)
    return cv2.remap(ideal, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def write_synthetic_euroc(
    root: str | Path,
    n_frames: int = 8,
    seed: int = 0,
    width: int = 160,
    height: int = 120,
    fps: float = 20.0,
    speed_mps: float = 4.0,
    yaw_rate_dps: float = 10.0,
    climb_mps: float = 0.5,
    city: City | None = None,
    gray: bool = True,
    baseline_m: float = 0.11,
) -> SyntheticEuroc:
    """Render a short stereo flight and write it in the EuRoC layout under ``root/mav0``.

    Args:
        root: the sequence directory (created).
        n_frames: stereo frames.
        seed: the city's (when not given) and the start pose's seed.
        width, height: image size, pixels.
        fps: camera rate; ground truth is written at 5 times that rate, offset by a third of a sample.
        speed_mps, yaw_rate_dps, climb_mps: the motion.
        city: the scene (default ``generate_city(seed, size_m=120)``).
        gray: write grey images (as EuRoC) rather than RGB.
        baseline_m: distance along cam0's x axis to cam1, metres (EuRoC's rig: 0.11 m, made for rooms;
            city streets at 10-60 m want more).
    """
    root = Path(root)
    city = generate_city(seed, size_m=120.0) if city is None else city
    start = street_view_pose(city, seed).inverse()  # world_from_cam of a good street view
    fwd = start.R[:, 2]
    yaw0, pitch = math.atan2(fwd[1], fwd[0]), -math.asin(float(np.clip(fwd[2], -1, 1)))
    p0 = start.t
    heading = np.array([math.cos(yaw0), math.sin(yaw0), 0.0])

    def world_from_cam0(t: float) -> Rigid3:
        p = p0 + speed_mps * t * heading + np.array([0.0, 0.0, climb_mps * t])
        return look_from(p, yaw0 + math.radians(yaw_rate_dps) * t, pitch).inverse()

    f = (width / 2) / math.tan(math.radians(40.0))
    cam0 = Intrinsics(
        f,
        f * 1.003,
        width / 2 - 0.5 + 1.7,
        height / 2 - 0.5 - 1.2,
        width,
        height,
        np.array([-0.18, 0.04, 0.0012, -0.0009]),
    )
    cam1 = Intrinsics(
        f * 0.995,
        f * 0.998,
        width / 2 - 0.5 - 1.1,
        height / 2 - 0.5 + 0.8,
        width,
        height,
        np.array([-0.16, 0.03, -0.0008, 0.0011]),
    )
    body_from_cam0 = Rigid3(
        rotvec_to_matrix(np.array([0.01, -0.02, 0.015])) @ _BODY_FROM_CAM_AXES,
        np.array([0.02, 0.06, -0.01]),
        "body",
        "cam",
    )
    cam0_from_cam1 = Rigid3(
        rotvec_to_matrix(np.array([0.006, -0.012, 0.009])),
        np.array([baseline_m, 0.002, -0.0015]),
        "cam",
        "cam",
    )
    body_from_cam1 = (body_from_cam0 @ cam0_from_cam1.with_frames("cam", None)).with_frames("body", "cam")
    cam0_from_body = body_from_cam0.inverse()

    mav = root / "mav0"
    ts_ns = EUROC_T0_NS + np.round(np.arange(n_frames) / fps * 1e9).astype(np.int64)
    world_from_body = []
    for name, intr, body_from_cam in (("cam0", cam0, body_from_cam0), ("cam1", cam1, body_from_cam1)):
        rows = ["#timestamp [ns],filename\n"]
        for k, t_ns in enumerate(ts_ns):
            t = (t_ns - EUROC_T0_NS) * 1e-9
            wfb = world_from_cam0(t).with_frames(None, None) @ cam0_from_body.with_frames(None, None)
            if name == "cam0":
                world_from_body.append(wfb.with_frames("world", "body"))
            cam_from_world = (wfb @ body_from_cam.with_frames(None, None)).inverse()
            image = _distorted_render(city, intr, cam_from_world)
            write_image(mav / name / "data" / f"{t_ns}.png", to_gray(image) if gray else image)
            rows.append(f"{t_ns},{t_ns}.png\n")
            del k
        write_text_atomic(mav / name / "data.csv", "".join(rows))
        write_text_atomic(mav / name / "sensor.yaml", _sensor_yaml(intr, body_from_cam, fps))

    gt_rate = 5 * fps
    t_gt = np.arange(-2, 5 * n_frames + 2) / gt_rate + 1.0 / (3 * gt_rate)
    lines = [
        "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z [], "
        "v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], b_w_RS_S_x [rad s^-1], b_w_RS_S_y [rad s^-1], "
        "b_w_RS_S_z [rad s^-1], b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], b_a_RS_S_z [m s^-2]\n"
    ]
    for t in t_gt:
        wfb = world_from_cam0(float(t)).with_frames(None, None) @ cam0_from_body.with_frames(None, None)
        q = matrix_to_quaternion(wfb.R)
        vals = [*wfb.t, *q] + [0.0] * 9
        lines.append(f"{EUROC_T0_NS + int(round(t * 1e9))}," + ",".join(f"{v:.9f}" for v in vals) + "\n")
    write_text_atomic(mav / "state_groundtruth_estimate0" / "data.csv", "".join(lines))
    return SyntheticEuroc(root, ts_ns, world_from_body, body_from_cam0, body_from_cam1, cam0, cam1, city)
