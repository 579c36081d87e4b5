"""Loose GPS fusion: anchor the odometry's drift to GPS fixes with a smoothly varying correction.

The odometry gives ``odom_from_left`` (its world is ``odom``); GPS gives positions in a local
metric ``world`` (z up, metres). :class:`GpsFusion` keeps a rigid correction ``world_from_odom`` and
returns ``world_from_left = world_from_odom @ odom_from_left`` for every frame. The correction is
re-fitted whenever fixes arrive:

1. **Gating**: a fix whose innovation (distance between the GPS position and the corrected odometry
   position at the fix time) exceeds ``gate_sigma`` times ``sqrt(accuracy^2 + sigma_pred^2)`` is
   rejected; ``sigma_pred`` (how far the correction may have drifted) grows with the distance flown
   since the last accepted fix (``drift_fraction`` of it), so that a long outage re-opens the gate
   but a sudden multipath jump of 20 m under a few metres' stated accuracy does not get in.
2. **Robust sliding-window fit**: over the accepted fixes of the last ``window_s`` seconds, a
   weighted rigid Umeyama fit of odometry positions onto GPS positions, iterated with Cauchy weights
   (scale ``cauchy_scale`` times the stated accuracy) and by recency (``exp(-age / recency_s)``: the
   drift makes old fixes less telling about the present) and tied to the previous correction by a few
   pseudo-points (``prior_weight``), which also fixes the rotation about a straight flight's line.
   Until the flown positions span ``min_span_m`` in two directions only the translation is fitted.
3. **Recovery**: when every fix has been rejected for ``reset_after_s`` seconds (longer than a
   multipath episode), the correction itself is wrong: it is re-aligned robustly (RANSAC) on those
   fixes if most of them agree. When the caller says the odometry tracked through the episode
   (``tracking``; lost in under a quarter of its frames), a good odometry is believed over a GPS
   that jumped: the episode must then last ``reset_while_tracking_s``. A re-alignment is a new
   target, reached under the rate limit below like any other correction (never a jump).
Translation only (``estimate_rotation`` False) with ``odometry_drift_fraction`` > 0, step 2 is a
Kalman filter on the offset instead: its variance grows as the odometry flies (``(fraction)^2 x
100 m`` per metre: 1 % gives 1 m after 100 m, 2 m after 400 m) and each fix weighs by its stated
accuracy (``vertical_accuracy_factor`` times worse vertically, as receivers are), inflated for
the fixes within ``fix_correlation_s`` of each other (a receiver's errors persist for seconds). A good odometry is then moved by the GPS only as far as its own drift
allows, instead of taking on the fixes' metres of multipath. With ``rotation_known`` the start
position is taken as known to ``base_sigma_m`` as well (the odometry started from a given pose).

4. **Rate limit**: once initialised, the correction may move the current position by at most
   ``max_correction_mps`` metres per second and turn by ``max_rotation_dps`` degrees per second: a
   bad fit cannot teleport the vehicle, only lean on it. Fixes are gated against the latest fit
   (where the correction is heading), not against the rate-limited one.

Usable online (one :meth:`GpsFusion.update` per frame) and offline (:func:`fuse_trajectory`).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from skyrecon.core.rigid import Rigid3, rotvec_to_matrix
from skyrecon.errors import EstimationError, InputError
from skyrecon.io.gps import GpsFix
from skyrecon.sfm.align import robust_umeyama, umeyama

__all__ = ["GpsFusionSettings", "GpsFusion", "GpsUpdate", "fuse_trajectory"]


@dataclass(frozen=True)
class GpsFusionSettings:
    """Tuning of :class:`GpsFusion` (metres, seconds, degrees); see the module docstring."""

    window_s: float = 60.0
    recency_s: float = 10.0
    gate_sigma: float = 3.0
    drift_fraction: float = 0.05
    base_sigma_m: float = 1.0
    cauchy_scale: float = 1.5
    prior_weight: float = 0.1
    min_span_m: float = 10.0
    max_correction_mps: float = 1.5
    max_rotation_dps: float = 3.0
    irls_iterations: int = 5
    reset_after_s: float = 15.0
    reset_while_tracking_s: float = 60.0
    odometry_drift_fraction: float = 0.0
    fix_correlation_s: float = 2.0
    vertical_accuracy_factor: float = 2.0

    def __post_init__(self) -> None:
        for name in (
            "window_s",
            "gate_sigma",
            "cauchy_scale",
            "min_span_m",
            "max_correction_mps",
            "max_rotation_dps",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise InputError(f"GPS fusion setting {name} must be positive, got {v}")


@dataclass
class GpsUpdate:
    """What one fix did: ``accepted`` or rejected, its ``innovation_m`` and the gate it met."""

    time_s: float
    accepted: bool
    innovation_m: float
    gate_m: float


@dataclass
class GpsFusion:
    """Online loose fusion (see the module docstring).

    Args:
        settings: :class:`GpsFusionSettings`.
        world_from_odom: the initial correction (e.g. from ``--init-pose``); its rotation is kept until
            the flight spans ``min_span_m`` when ``estimate_rotation``.
        estimate_rotation: fit the rotation too (else translation only: the odometry's world is
            already level and oriented, e.g. started with the true initial pose).
        rotation_known: ``world_from_odom``'s rotation is already about right (e.g. the odometry
            started from a given world pose): fixes are gated from the first one and the rotation
            is only refined (rate limited), not found from scratch.
    """

    settings: GpsFusionSettings = field(default_factory=GpsFusionSettings)
    world_from_odom: Rigid3 = field(default_factory=lambda: Rigid3.identity("world", "odom"))
    estimate_rotation: bool = True
    rotation_known: bool = False
    updates: list[GpsUpdate] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.world_from_odom = self.world_from_odom.with_frames("world", "odom")
        self._window: deque[tuple[float, np.ndarray, np.ndarray, float]] = deque()
        self._t_prev: float | None = None
        self._p_prev: np.ndarray | None = None
        self._since_accept_m = 0.0
        self._rejected: deque[tuple[float, np.ndarray, np.ndarray, float]] = deque()
        self.resets = 0
        self._tracking_known = False
        self._episode_frames = self._episode_lost = 0  # frames (and lost ones) since fixes began to fail
        self._fitted = self.world_from_odom  # the latest fit: what fixes are gated against
        self._kalman = not self.estimate_rotation and self.settings.odometry_drift_fraction > 0
        self._kf_t: np.ndarray | None = None  # the Kalman offset (translation only), metres
        self._kf_var = np.zeros(3)  # its variance per axis (x, y, z), m^2
        self._axis_scale = np.array([1.0, 1.0, self.settings.vertical_accuracy_factor**2])
        self._kf_last_fix_s: float | None = None
        self._has_translation = False
        if self._kalman and self.rotation_known:
            # the odometry started from a given world pose: its position is known too, to about
            # base_sigma_m (a home position averaged before take-off), and the fixes refine it
            self._has_translation = True
            self._kf_t = self.world_from_odom.t.copy()
            self._kf_var = np.full(3, self.settings.base_sigma_m**2)
        self._has_rotation = self.rotation_known or not self.estimate_rotation

    # ----- the public step ------------------------------------------------------------------
    @property
    def initialised(self) -> bool:
        """A fix has been accepted (the correction's translation is anchored)."""
        return self._has_translation

    @property
    def aligned(self) -> bool:
        """The correction's rotation is known too (or was given): fused poses are in the GPS world.
        Before that (the flight has not turned yet) only the position at the fixes is anchored."""
        return self._has_translation and self._has_rotation

    @property
    def accepted(self) -> int:
        return sum(u.accepted for u in self.updates)

    @property
    def rejected(self) -> int:
        return sum(not u.accepted for u in self.updates)

    def update(
        self,
        time_s: float,
        odom_from_left: Rigid3,
        fixes: GpsFix | Sequence[GpsFix] | None = None,
        tracking: bool | None = None,
    ) -> Rigid3:
        """Advance to a frame at ``time_s`` with the odometry pose ``odom_from_left`` and the fixes
        received since the previous frame (their times may lie between the two frames: the
        odometry position is interpolated there). ``tracking``: whether the odometry tracks at
        this frame (not lost; None: unknown), see the module's recovery rule.

        Returns:
            ``world_from_left`` of this frame, metres.
        """
        p = np.asarray(odom_from_left.t, np.float64)
        if self._p_prev is not None:
            step = float(np.linalg.norm(p - self._p_prev))
            self._since_accept_m += step
            self._kf_var += self.settings.odometry_drift_fraction**2 * 100.0 * step
        dt = 0.0 if self._t_prev is None else max(0.0, float(time_s) - self._t_prev)
        fix_list = [] if fixes is None else ([fixes] if isinstance(fixes, GpsFix) else list(fixes))
        any_new = False
        if self._rejected and tracking is not None:
            self._episode_frames += 1
            self._episode_lost += not tracking
        elif not self._rejected:
            self._episode_frames = self._episode_lost = 0
        self._tracking_known = tracking is not None
        for f in fix_list:
            any_new |= self._consider(f, self._odom_at(f.time_s, time_s, p))
        if any_new:
            self._refit(p, dt)
        self._t_prev, self._p_prev = float(time_s), p
        return (
            self.world_from_odom.with_frames(None, None) @ odom_from_left.with_frames(None, None)
        ).with_frames("world", "left")

    # ----- internals -------------------------------------------------------------------------
    def _odom_at(self, t_fix: float, t_now: float, p_now: np.ndarray) -> np.ndarray:
        if self._t_prev is None or self._p_prev is None or t_now <= self._t_prev:
            return p_now
        w = float(np.clip((t_fix - self._t_prev) / (t_now - self._t_prev), 0.0, 1.0))
        return (1 - w) * self._p_prev + w * p_now

    def _consider(self, fix: GpsFix, p_odom: np.ndarray) -> bool:
        s = self.settings
        predicted = self._fitted.apply(p_odom)
        innovation = float(np.linalg.norm(fix.position - predicted))
        if not self._has_translation:
            self.world_from_odom = Rigid3(
                self.world_from_odom.R, self.world_from_odom.t + (fix.position - predicted), "world", "odom"
            )
            self._fitted = self.world_from_odom
            self._kf_t, self._kf_var = self.world_from_odom.t.copy(), fix.accuracy_m**2 * self._axis_scale
            self._has_translation = True
            gate, ok = math.inf, True
        elif not self._has_rotation:
            gate, ok = math.inf, True  # the odometry's orientation is still unknown: take all, fit robustly
        else:
            sigma_pred = s.base_sigma_m + s.drift_fraction * self._since_accept_m
            gate = s.gate_sigma * math.hypot(fix.accuracy_m, sigma_pred)
            ok = innovation <= gate
        self.updates.append(GpsUpdate(fix.time_s, ok, innovation, gate))
        entry = (fix.time_s, p_odom.copy(), fix.position.copy(), fix.accuracy_m)
        if ok:
            if self._kalman and self._kf_t is not None and math.isfinite(gate):
                self._kalman_update(fix, p_odom)
            self._window.append(entry)
            self._rejected.clear()
            self._since_accept_m = 0.0
            while self._window and self._window[0][0] < fix.time_s - s.window_s:
                self._window.popleft()
            return True
        self._rejected.append(entry)
        need = s.reset_after_s
        if self._tracking_known and self._episode_lost < 0.25 * max(1, self._episode_frames):
            need = max(need, s.reset_while_tracking_s)
        if fix.time_s - self._rejected[0][0] >= need:
            return self._reset_from_rejected()
        return False

    def _reset_from_rejected(self) -> bool:
        """Every fix rejected for ``reset_after_s``: a multipath episode lasts seconds, so it is the
        correction that went wrong (e.g. a first alignment on a barely turning flight). Re-align
        robustly on the rejected fixes when most of them agree; returns whether it did."""
        src = np.array([w[1] for w in self._rejected])
        dst = np.array([w[2] for w in self._rejected])
        acc = float(np.median([w[3] for w in self._rejected]))
        prev = self.world_from_odom
        try:
            if (
                self._has_rotation
                and self.estimate_rotation
                and np.ptp(src, axis=0).max() >= self.settings.min_span_m
            ):
                res = robust_umeyama(src, dst, threshold=3.0 * acc, with_scale=False, seed=0)
                R, t, inl = res.transform.R, res.transform.t, res.inliers
            else:  # keep the rotation, move the translation (a median is robust to a minority of jumps)
                R = prev.R
                t = np.median(dst - src @ R.T, axis=0)
                inl = np.linalg.norm(src @ R.T + t - dst, axis=1) < 3.0 * acc
        except EstimationError:
            return False
        if inl.sum() < 0.6 * len(src):
            return False
        self._fitted = Rigid3(R, t, "world", "odom")  # the target; the output gets there rate limited
        self._kf_t, self._kf_var = np.asarray(t, np.float64).copy(), acc**2 * self._axis_scale
        self._window = deque(w for w, keep in zip(self._rejected, inl) if keep)
        self._rejected.clear()
        self._since_accept_m = 0.0
        self.resets += 1
        return True

    def _kalman_update(self, fix: GpsFix, p_odom: np.ndarray) -> None:
        """One accepted fix into the offset's Kalman filter (see the module)."""
        assert self._kf_t is not None
        s = self.settings
        gap = math.inf if self._kf_last_fix_s is None else max(1e-3, fix.time_s - self._kf_last_fix_s)
        r = fix.accuracy_m**2 * max(1.0, s.fix_correlation_s / gap) * self._axis_scale
        y = fix.position - (self.world_from_odom.R @ p_odom + self._kf_t)
        k = self._kf_var / (self._kf_var + r)
        self._kf_t = self._kf_t + k * y
        self._kf_var = (1.0 - k) * self._kf_var
        self._kf_last_fix_s = fix.time_s

    def _fit(self) -> Rigid3:
        if self._kalman and self._kf_t is not None:
            return Rigid3(self.world_from_odom.R, self._kf_t, "world", "odom")
        s = self.settings
        src = np.array([w[1] for w in self._window])
        dst = np.array([w[2] for w in self._window])
        acc = np.array([w[3] for w in self._window])
        prev = self.world_from_odom
        rotate = self.estimate_rotation and len(src) >= 3 and float(np.ptp(src, axis=0).max()) >= s.min_span_m
        if rotate and not self._has_rotation:
            # the first alignment needs a turn: on a straight line the roll about it is unobservable
            spread = np.linalg.svd(src - src.mean(axis=0), compute_uv=False) / math.sqrt(len(src))
            # ... and one wide against the fixes' accuracy, or their errors become a rotation error
            rotate = bool(spread[1] >= max(s.min_span_m / 8, 1.0 * float(np.median(acc))))
        # pseudo-points tying the fit to the previous correction (about the window's centre)
        c = src.mean(axis=0)
        span = max(s.min_span_m, float(np.ptp(src, axis=0).max()))
        offsets = np.vstack([np.eye(3), -np.eye(3)]) * span / 2
        prior_src = c + offsets
        prior_dst = prev.apply(prior_src)
        age = self._window[-1][0] - np.array([w[0] for w in self._window])
        w_fix = np.exp(-age / s.recency_s) / acc**2  # the odometry drifts: recent fixes say more about now
        R, t = prev.R, prev.t
        for _ in range(s.irls_iterations):
            r = np.linalg.norm(src @ R.T + t - dst, axis=1)
            w = w_fix / (1.0 + (r / (s.cauchy_scale * acc)) ** 2)
            if rotate:
                w_prior = np.full(len(prior_src), s.prior_weight * w.sum() / len(prior_src))
                try:
                    T = umeyama(
                        np.vstack([src, prior_src]),
                        np.vstack([dst, prior_dst]),
                        with_scale=False,
                        weights=np.concatenate([w, w_prior]),
                    ).transform
                    R, t = T.R, T.t
                    continue
                except EstimationError:
                    pass
            t = (w @ (dst - src @ R.T)) / w.sum()
        return Rigid3(R, t, "world", "odom")

    def _first_alignment(self, fit: Rigid3) -> Rigid3:
        """The first rigid alignment: RANSAC over the window (fixes taken before the orientation was
        known are not gated), then drop the outliers from the window and refit."""
        src = np.array([w[1] for w in self._window])
        dst = np.array([w[2] for w in self._window])
        acc = np.array([w[3] for w in self._window])
        try:
            res = robust_umeyama(src, dst, threshold=3.0 * float(np.median(acc)), with_scale=False, seed=0)
        except EstimationError:
            return fit
        if res.num_inliers < 3 or np.ptp(src[res.inliers], axis=0).max() < self.settings.min_span_m:
            return fit
        self._window = deque(w for w, keep in zip(self._window, res.inliers) if keep)
        self.world_from_odom = Rigid3(res.transform.R, res.transform.t, "world", "odom")
        return self._fit()

    def _refit(self, p_now: np.ndarray, dt: float) -> None:
        s = self.settings
        fit = self._fit()
        rotating = self.estimate_rotation and not np.allclose(fit.R, self.world_from_odom.R, atol=1e-12)
        if rotating and not self._has_rotation:
            self.world_from_odom = self._first_alignment(fit)  # taken as it is, not rate limited
            self._fitted = self.world_from_odom
            self._has_rotation = True
            return
        self._fitted = fit
        prev = self.world_from_odom
        if len(self._window) <= 1:
            self.world_from_odom = fit
            return
        dt = max(dt, 1e-3)
        rel = prev.R.T @ fit.R
        angle = math.degrees(np.linalg.norm(Rigid3(rel).rotvec))
        a_rot = min(1.0, s.max_rotation_dps * dt / angle) if angle > 1e-9 else 1.0
        R_new = prev.R @ rotvec_to_matrix(Rigid3(rel).rotvec * a_rot)
        target = fit.apply(p_now)
        here = prev.apply(p_now)
        move = target - here
        dist = float(np.linalg.norm(move))
        a_t = min(1.0, s.max_correction_mps * dt / dist) if dist > 1e-12 else 1.0
        t_new = here + a_t * move - R_new @ p_now
        self.world_from_odom = Rigid3(R_new, t_new, "world", "odom")


def fuse_trajectory(
    times_s: np.ndarray,
    odom_from_left: Sequence[Rigid3],
    fixes: Sequence[GpsFix],
    settings: GpsFusionSettings | None = None,
    world_from_odom: Rigid3 | None = None,
    estimate_rotation: bool = True,
) -> tuple[list[Rigid3], GpsFusion]:
    """Run :class:`GpsFusion` over a whole trajectory: each frame gets the fixes timed after the
    previous frame and up to its own time (fixes before the first frame go to the first frame).

    Returns:
        (``world_from_left`` per frame, the fusion with its per-fix log).
    """
    t = np.asarray(times_s, np.float64)
    if len(t) != len(odom_from_left):
        raise InputError(f"{len(t)} times for {len(odom_from_left)} poses")
    fusion = GpsFusion(
        settings or GpsFusionSettings(),
        world_from_odom if world_from_odom is not None else Rigid3.identity("world", "odom"),
        estimate_rotation,
    )
    fix_t = np.array([f.time_s for f in fixes])
    out = []
    lo = 0
    for k, (tk, pose) in enumerate(zip(t, odom_from_left)):
        hi = int(np.searchsorted(fix_t, tk, side="right")) if k < len(t) - 1 else len(fixes)
        out.append(fusion.update(float(tk), pose, list(fixes[lo:hi])))
        lo = hi
    return out, fusion
