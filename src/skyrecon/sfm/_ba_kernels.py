"""Numba kernels of the bundle adjuster: projection with analytic Jacobians, normal equations,
Schur complement on the point blocks and back-substitution.

Camera model (per camera row ``[fx, fy, cx, cy, k1, k2]``, pixels, top-left pixel centre (0, 0))::

    P = R X + t                      (camera frame, OpenCV axes, R/t = cam_from_world)
    x, y = P0 / P2, P1 / P2          (normalised)
    d = 1 + k1 r^2 + k2 r^4          (r^2 = x^2 + y^2)
    u = fx d x + cx,  v = fy d y + cy

Pose update (left perturbation in the camera frame): ``R <- exp([dw]x) R``, ``t <- t + dt``, so
``dP/ddw = -[R X]x`` and ``dP/ddt = I``. Intrinsic update: ``fx <- fx + df``, ``fy <- fy + df fy/fx``
(aspect kept), ``k1 <- k1 + dk1``, ``k2 <- k2 + dk2``.

Residuals are divided by each observation's sigma (pixels) so that robust loss scales are in
sigma units. The reduced camera system has six columns per variable pose (``w0 w1 w2 t0 t1 t2``) followed
by three per variable camera (``f k1 k2``); a coordinate held fixed has a zero Jacobian column
and a unit diagonal, so its step is zero.

The reduced system is stored block-sparse: block ``A`` is pose ``A`` (6 columns) for ``A < n_pose``
and intrinsics block ``A - n_pose`` (3 columns) above; ``slot[A, B]`` (int32, -1 where empty) is
the row of a ``(n_slots, 6, 6)`` value array that holds block ``(A, B)`` (its top-left
``size(A) x size(B)`` corner). Pose-pose and pose-intrinsics blocks are kept only for ``A <= B``
(the lower ones are their transposes); intrinsics-intrinsics blocks are kept in both orders.
"""

from __future__ import annotations

import numba as nb
import numpy as np

LOSS_TRIVIAL = 0
LOSS_HUBER = 1
LOSS_CAUCHY = 2


@nb.njit(cache=True, inline="always")
def _rho(s: float, c2: float, kind: int) -> tuple[float, float]:
    """Robust loss of a squared residual s: (rho(s), rho'(s)) with rho(s) ~ s for small s."""
    if kind == LOSS_CAUCHY:
        return c2 * np.log1p(s / c2), 1.0 / (1.0 + s / c2)
    if kind == LOSS_HUBER:
        if s <= c2:
            return s, 1.0
        r = np.sqrt(s)
        c = np.sqrt(c2)
        return 2.0 * c * r - c2, c / r
    return s, 1.0


@nb.njit(cache=True)
def evaluate(
    R: np.ndarray,
    t: np.ndarray,
    X: np.ndarray,
    cams: np.ndarray,
    cam_of_img: np.ndarray,
    obs_img: np.ndarray,
    obs_pt: np.ndarray,
    obs_uv: np.ndarray,
    obs_inv_sigma: np.ndarray,
    loss: int,
    loss_c2: float,
    want_jac: bool,
    res: np.ndarray,
    Jp: np.ndarray,
    Ji: np.ndarray,
    Jx: np.ndarray,
    w: np.ndarray,
) -> float:
    """Residuals (and Jacobians) of every observation; returns the robust cost 0.5 sum rho(|r|^2).

    Observations whose point is behind (or on) the camera get zero residual, zero Jacobian and
    a fixed penalty cost (so a step moving points behind cameras is rejected).
    """
    n = obs_img.shape[0]
    cost = 0.0
    for o in range(n):
        i = obs_img[o]
        p = obs_pt[o]
        c = cam_of_img[i]
        fx = cams[c, 0]
        fy = cams[c, 1]
        cx = cams[c, 2]
        cy = cams[c, 3]
        k1 = cams[c, 4]
        k2 = cams[c, 5]
        X0 = X[p, 0]
        X1 = X[p, 1]
        X2 = X[p, 2]
        q0 = R[i, 0, 0] * X0 + R[i, 0, 1] * X1 + R[i, 0, 2] * X2
        q1 = R[i, 1, 0] * X0 + R[i, 1, 1] * X1 + R[i, 1, 2] * X2
        q2 = R[i, 2, 0] * X0 + R[i, 2, 1] * X1 + R[i, 2, 2] * X2
        P0 = q0 + t[i, 0]
        P1 = q1 + t[i, 1]
        P2 = q2 + t[i, 2]
        s = obs_inv_sigma[o]
        if not P2 > 1e-12:
            res[o, 0] = 0.0
            res[o, 1] = 0.0
            w[o] = 0.0
            if want_jac:
                for a in range(6):
                    Jp[o, 0, a] = 0.0
                    Jp[o, 1, a] = 0.0
                for a in range(3):
                    Ji[o, 0, a] = 0.0
                    Ji[o, 1, a] = 0.0
                    Jx[o, 0, a] = 0.0
                    Jx[o, 1, a] = 0.0
            cost += 0.5 * _rho(1e4, loss_c2, loss)[0]
            continue
        iz = 1.0 / P2
        x = P0 * iz
        y = P1 * iz
        r2 = x * x + y * y
        d = 1.0 + r2 * (k1 + k2 * r2)
        u = fx * d * x + cx
        v = fy * d * y + cy
        e0 = (u - obs_uv[o, 0]) * s
        e1 = (v - obs_uv[o, 1]) * s
        res[o, 0] = e0
        res[o, 1] = e1
        rho, drho = _rho(e0 * e0 + e1 * e1, loss_c2, loss)
        cost += 0.5 * rho
        w[o] = drho
        if not want_jac:
            continue
        dd = k1 + 2.0 * k2 * r2
        a00 = fx * (d + 2.0 * x * x * dd) * s
        a01 = fx * (2.0 * x * y * dd) * s
        a10 = fy * (2.0 * x * y * dd) * s
        a11 = fy * (d + 2.0 * y * y * dd) * s
        B00 = a00 * iz
        B01 = a01 * iz
        B02 = -(a00 * x + a01 * y) * iz
        B10 = a10 * iz
        B11 = a11 * iz
        B12 = -(a10 * x + a11 * y) * iz
        # translation part: dP/dt = I
        Jp[o, 0, 3] = B00
        Jp[o, 0, 4] = B01
        Jp[o, 0, 5] = B02
        Jp[o, 1, 3] = B10
        Jp[o, 1, 4] = B11
        Jp[o, 1, 5] = B12
        # rotation part: dP/dw = -[q]x = [[0, q2, -q1], [-q2, 0, q0], [q1, -q0, 0]]
        Jp[o, 0, 0] = -B01 * q2 + B02 * q1
        Jp[o, 0, 1] = B00 * q2 - B02 * q0
        Jp[o, 0, 2] = -B00 * q1 + B01 * q0
        Jp[o, 1, 0] = -B11 * q2 + B12 * q1
        Jp[o, 1, 1] = B10 * q2 - B12 * q0
        Jp[o, 1, 2] = -B10 * q1 + B11 * q0
        # point part: dP/dX = R
        for a in range(3):
            Jx[o, 0, a] = B00 * R[i, 0, a] + B01 * R[i, 1, a] + B02 * R[i, 2, a]
            Jx[o, 1, a] = B10 * R[i, 0, a] + B11 * R[i, 1, a] + B12 * R[i, 2, a]
        # intrinsics: f (fy follows with the aspect), k1, k2
        Ji[o, 0, 0] = d * x * s
        Ji[o, 1, 0] = d * y * (fy / fx) * s
        Ji[o, 0, 1] = fx * x * r2 * s
        Ji[o, 1, 1] = fy * y * r2 * s
        Ji[o, 0, 2] = fx * x * r2 * r2 * s
        Ji[o, 1, 2] = fy * y * r2 * r2 * s
    return cost


@nb.njit(cache=True)
def build_normal_equations(
    res: np.ndarray,
    Jp: np.ndarray,
    Ji: np.ndarray,
    Jx: np.ndarray,
    w: np.ndarray,
    obs_pt: np.ndarray,
    obs_pose: np.ndarray,
    obs_intr: np.ndarray,
    intr_base: int,
    pt_var: np.ndarray,
    pose_free: np.ndarray,
    intr_free: np.ndarray,
    slot: np.ndarray,
    n_pose: int,
    U: np.ndarray,
    gc: np.ndarray,
    V: np.ndarray,
    gx: np.ndarray,
    Wp: np.ndarray,
    Wi: np.ndarray,
) -> None:
    """Accumulate the normal equations in block form.

    Column layout of the reduced system: pose block k at ``6 k .. 6 k + 5``, intrinsics block g
    at ``intr_base + 3 g .. + 2`` (held-fixed coordinates have zero Jacobian columns).
    Outputs (zeroed by the caller): ``U = Jc^T w Jc`` in the blocks ``slot`` numbers (see the
    module docstring), ``gc = Jc^T w r``, point blocks
    ``V[q] = Jx^T w Jx``, ``gx[q] = Jx^T w r``, and per observation ``Wp[o] = Jp^T w Jx`` (6 x 3),
    ``Wi[o] = Ji^T w Jx`` (3 x 3). Columns of held coordinates are multiplied by
    ``pose_free[k]`` (n_pose, 6) and ``intr_free`` (3,) (1.0 free, 0.0 held).
    """
    n = obs_pt.shape[0]
    jp = np.empty((2, 6))
    ji = np.empty((2, 3))
    for o in range(n):
        wo = w[o]
        k = obs_pose[o]
        g = obs_intr[o]
        q = pt_var[obs_pt[o]]
        if wo == 0.0:
            continue
        r0 = res[o, 0]
        r1 = res[o, 1]
        if g >= 0:
            for a in range(3):
                ji[0, a] = Ji[o, 0, a] * intr_free[a]
                ji[1, a] = Ji[o, 1, a] * intr_free[a]
        if k >= 0:
            for a in range(6):
                jp[0, a] = Jp[o, 0, a] * pose_free[k, a]
                jp[1, a] = Jp[o, 1, a] * pose_free[k, a]
            b = 6 * k
            skk = slot[k, k]
            skg = slot[k, n_pose + g] if g >= 0 else -1
            for a in range(6):
                ja0 = wo * jp[0, a]
                ja1 = wo * jp[1, a]
                gc[b + a] += ja0 * r0 + ja1 * r1
                for c in range(a, 6):
                    v = ja0 * jp[0, c] + ja1 * jp[1, c]
                    U[skk, a, c] += v
                    if c != a:
                        U[skk, c, a] += v
                if g >= 0:
                    for c in range(3):
                        U[skg, a, c] += ja0 * ji[0, c] + ja1 * ji[1, c]
                if q >= 0:
                    for c in range(3):
                        Wp[o, a, c] = ja0 * Jx[o, 0, c] + ja1 * Jx[o, 1, c]
        if g >= 0:
            bi = intr_base + 3 * g
            sgg = slot[n_pose + g, n_pose + g]
            for a in range(3):
                ja0 = wo * ji[0, a]
                ja1 = wo * ji[1, a]
                gc[bi + a] += ja0 * r0 + ja1 * r1
                for c in range(3):
                    U[sgg, a, c] += ja0 * ji[0, c] + ja1 * ji[1, c]
                if q >= 0:
                    for c in range(3):
                        Wi[o, a, c] = ja0 * Jx[o, 0, c] + ja1 * Jx[o, 1, c]
        if q >= 0:
            for a in range(3):
                xa0 = wo * Jx[o, 0, a]
                xa1 = wo * Jx[o, 1, a]
                gx[q, a] += xa0 * r0 + xa1 * r1
                for c in range(3):
                    V[q, a, c] += xa0 * Jx[o, 0, c] + xa1 * Jx[o, 1, c]


@nb.njit(cache=True, inline="always")
def _inv3(A: np.ndarray, out: np.ndarray) -> bool:
    a, b, c = A[0, 0], A[0, 1], A[0, 2]
    d, e, f = A[1, 0], A[1, 1], A[1, 2]
    g, h, k = A[2, 0], A[2, 1], A[2, 2]
    c00 = e * k - f * h
    c01 = -(d * k - f * g)
    c02 = d * h - e * g
    det = a * c00 + b * c01 + c * c02
    if not (abs(det) > 1e-300) or not np.isfinite(det):
        return False
    idet = 1.0 / det
    out[0, 0] = c00 * idet
    out[1, 0] = c01 * idet
    out[2, 0] = c02 * idet
    out[0, 1] = -(b * k - c * h) * idet
    out[1, 1] = (a * k - c * g) * idet
    out[2, 1] = -(a * h - b * g) * idet
    out[0, 2] = (b * f - c * e) * idet
    out[1, 2] = -(a * f - c * d) * idet
    out[2, 2] = (a * e - b * d) * idet
    return True


@nb.njit(cache=True)
def schur_complement(
    V: np.ndarray,
    gx: np.ndarray,
    Wp: np.ndarray,
    Wi: np.ndarray,
    lam: float,
    pt_ptr: np.ndarray,
    pt_obs: np.ndarray,
    obs_pose: np.ndarray,
    obs_intr: np.ndarray,
    intr_base: int,
    slot: np.ndarray,
    n_pose: int,
    S: np.ndarray,
    rhs: np.ndarray,
    Vinv: np.ndarray,
) -> bool:
    """In place: ``S -= sum_p W_p Vinv_p W_p^T`` and ``rhs -= sum_p W_p Vinv_p gx_p`` with the
    damped point blocks ``V_p (1 + lam)`` on the diagonal (inverses stored in ``Vinv``).

    ``S`` (n_slots, 6, 6) holds the damped ``U`` in the blocks ``slot`` numbers and ``rhs`` holds
    ``gc`` on entry. ``pt_ptr``/``pt_obs`` list the observations of each variable point (CSR).
    Returns False when a point block is singular.
    """
    nq = V.shape[0]
    Vd = np.empty((3, 3))
    Vi = np.empty((3, 3))
    Tp = np.empty((64, 6, 3))
    Ti = np.empty((64, 3, 3))
    var = np.empty(64, np.int64)  # positions in the track of the observations in variable blocks
    ok = True
    for q in range(nq):
        for a in range(3):
            for b in range(3):
                Vd[a, b] = V[q, a, b]
            Vd[a, a] = V[q, a, a] * (1.0 + lam) + 1e-12
        if not _inv3(Vd, Vi):
            ok = False
            for a in range(3):
                for b in range(3):
                    Vi[a, b] = 0.0
        for a in range(3):
            for b in range(3):
                Vinv[q, a, b] = Vi[a, b]
        start = pt_ptr[q]
        stop = pt_ptr[q + 1]
        L = stop - start
        if L > Tp.shape[0]:
            Tp = np.empty((L, 6, 3))
            Ti = np.empty((L, 3, 3))
            var = np.empty(L, np.int64)
        n_var = 0
        for ia in range(L):
            o = pt_obs[start + ia]
            if obs_pose[o] >= 0 or obs_intr[o] >= 0:
                var[n_var] = ia
                n_var += 1
            if obs_pose[o] >= 0:
                for a in range(6):
                    for b in range(3):
                        Tp[ia, a, b] = (
                            Wp[o, a, 0] * Vi[0, b] + Wp[o, a, 1] * Vi[1, b] + Wp[o, a, 2] * Vi[2, b]
                        )
            if obs_intr[o] >= 0:
                for a in range(3):
                    for b in range(3):
                        Ti[ia, a, b] = (
                            Wi[o, a, 0] * Vi[0, b] + Wi[o, a, 1] * Vi[1, b] + Wi[o, a, 2] * Vi[2, b]
                        )
        # only observations in variable blocks couple blocks (a local adjustment's long tracks
        # are mostly observations in constant images)
        for va in range(n_var):
            ia = var[va]
            oa = pt_obs[start + ia]
            ka = obs_pose[oa]
            ga = obs_intr[oa]
            if ka >= 0:
                ba = 6 * ka
                for a in range(6):
                    rhs[ba + a] -= Tp[ia, a, 0] * gx[q, 0] + Tp[ia, a, 1] * gx[q, 1] + Tp[ia, a, 2] * gx[q, 2]
            if ga >= 0:
                bia = intr_base + 3 * ga
                for a in range(3):
                    rhs[bia + a] -= (
                        Ti[ia, a, 0] * gx[q, 0] + Ti[ia, a, 1] * gx[q, 1] + Ti[ia, a, 2] * gx[q, 2]
                    )
            for vb in range(n_var):
                ob = pt_obs[start + var[vb]]
                kb = obs_pose[ob]
                gb = obs_intr[ob]
                if ka >= 0 and kb >= ka:  # upper blocks; the lower ones are their transposes
                    sab = slot[ka, kb]
                    for a in range(6):
                        t0 = Tp[ia, a, 0]
                        t1 = Tp[ia, a, 1]
                        t2 = Tp[ia, a, 2]
                        for c in range(6):
                            S[sab, a, c] -= t0 * Wp[ob, c, 0] + t1 * Wp[ob, c, 1] + t2 * Wp[ob, c, 2]
                if ka >= 0 and gb >= 0:
                    sab = slot[ka, n_pose + gb]
                    for a in range(6):
                        for c in range(3):
                            S[sab, a, c] -= (
                                Tp[ia, a, 0] * Wi[ob, c, 0]
                                + Tp[ia, a, 1] * Wi[ob, c, 1]
                                + Tp[ia, a, 2] * Wi[ob, c, 2]
                            )
                if ga >= 0 and gb >= 0:
                    sab = slot[n_pose + ga, n_pose + gb]
                    for a in range(3):
                        for c in range(3):
                            S[sab, a, c] -= (
                                Ti[ia, a, 0] * Wi[ob, c, 0]
                                + Ti[ia, a, 1] * Wi[ob, c, 1]
                                + Ti[ia, a, 2] * Wi[ob, c, 2]
                            )
    return ok


@nb.njit(cache=True)
def block_pattern(
    pt_ptr: np.ndarray,
    pt_obs: np.ndarray,
    obs_pose: np.ndarray,
    obs_intr: np.ndarray,
    n_pose: int,
    slot: np.ndarray,
) -> int:
    """Number the non-empty blocks of the reduced system in ``slot`` (n_blocks, n_blocks) int32,
    -1 on entry (see the module docstring): every diagonal block, the pose-intrinsics block of
    every observation and the blocks coupled through each variable point. Blocks are numbered
    in row-major order; returns their count."""
    n_blocks = slot.shape[0]
    for a in range(n_blocks):
        slot[a, a] = 0
    for o in range(obs_pose.shape[0]):
        if obs_pose[o] >= 0 and obs_intr[o] >= 0:
            slot[obs_pose[o], n_pose + obs_intr[o]] = 0
    var = np.empty(64, np.int64)  # the observations of a point in variable blocks
    for q in range(pt_ptr.shape[0] - 1):
        if pt_ptr[q + 1] - pt_ptr[q] > var.shape[0]:
            var = np.empty(pt_ptr[q + 1] - pt_ptr[q], np.int64)
        n_var = 0
        for i in range(pt_ptr[q], pt_ptr[q + 1]):
            if obs_pose[pt_obs[i]] >= 0 or obs_intr[pt_obs[i]] >= 0:
                var[n_var] = pt_obs[i]
                n_var += 1
        for va in range(n_var):
            ka = obs_pose[var[va]]
            ga = obs_intr[var[va]]
            for vb in range(n_var):
                kb = obs_pose[var[vb]]
                gb = obs_intr[var[vb]]
                if ka >= 0 and kb >= ka:
                    slot[ka, kb] = 0
                if ka >= 0 and gb >= 0:
                    slot[ka, n_pose + gb] = 0
                if ga >= 0 and gb >= 0:
                    slot[n_pose + ga, n_pose + gb] = 0
    n = 0
    for a in range(n_blocks):
        for b in range(n_blocks):
            if slot[a, b] == 0:
                slot[a, b] = n
                n += 1
    return n


@nb.njit(cache=True)
def back_substitute(
    dc: np.ndarray,
    gx: np.ndarray,
    Wp: np.ndarray,
    Wi: np.ndarray,
    Vinv: np.ndarray,
    pt_ptr: np.ndarray,
    pt_obs: np.ndarray,
    obs_pose: np.ndarray,
    obs_intr: np.ndarray,
    intr_base: int,
    dx: np.ndarray,
) -> None:
    """Point steps ``dx_p = -Vinv_p (gx_p + sum_a W_a^T dc_a)`` given the camera step ``dc``."""
    nq = Vinv.shape[0]
    for q in range(nq):
        b0 = gx[q, 0]
        b1 = gx[q, 1]
        b2 = gx[q, 2]
        for kk in range(pt_ptr[q], pt_ptr[q + 1]):
            o = pt_obs[kk]
            k = obs_pose[o]
            if k >= 0:
                for a in range(6):
                    d = dc[6 * k + a]
                    b0 += Wp[o, a, 0] * d
                    b1 += Wp[o, a, 1] * d
                    b2 += Wp[o, a, 2] * d
            g = obs_intr[o]
            if g >= 0:
                for a in range(3):
                    d = dc[intr_base + 3 * g + a]
                    b0 += Wi[o, a, 0] * d
                    b1 += Wi[o, a, 1] * d
                    b2 += Wi[o, a, 2] * d
        for a in range(3):
            dx[q, a] = -(Vinv[q, a, 0] * b0 + Vinv[q, a, 1] * b1 + Vinv[q, a, 2] * b2)


@nb.njit(cache=True)
def rotate_left(R: np.ndarray, dw: np.ndarray, idx: np.ndarray) -> None:
    """``R[idx[k]] <- exp([dw[k]]x) R[idx[k]]`` in place (Rodrigues)."""
    for k in range(idx.shape[0]):
        i = idx[k]
        wx = dw[k, 0]
        wy = dw[k, 1]
        wz = dw[k, 2]
        th = np.sqrt(wx * wx + wy * wy + wz * wz)
        if th < 1e-14:
            A = np.eye(3)
            A[0, 1] = -wz
            A[0, 2] = wy
            A[1, 0] = wz
            A[1, 2] = -wx
            A[2, 0] = -wy
            A[2, 1] = wx
        else:
            kx = wx / th
            ky = wy / th
            kz = wz / th
            s = np.sin(th)
            c1 = 1.0 - np.cos(th)
            A = np.empty((3, 3))
            A[0, 0] = 1.0 + c1 * (-(ky * ky + kz * kz))
            A[1, 1] = 1.0 + c1 * (-(kx * kx + kz * kz))
            A[2, 2] = 1.0 + c1 * (-(kx * kx + ky * ky))
            A[0, 1] = -s * kz + c1 * kx * ky
            A[1, 0] = s * kz + c1 * kx * ky
            A[0, 2] = s * ky + c1 * kx * kz
            A[2, 0] = -s * ky + c1 * kx * kz
            A[1, 2] = -s * kx + c1 * ky * kz
            A[2, 1] = s * kx + c1 * ky * kz
        Rn = A @ R[i]
        # re-orthonormalise cheaply (Gram-Schmidt on rows) to stop drift
        r0 = Rn[0] / np.sqrt(Rn[0, 0] ** 2 + Rn[0, 1] ** 2 + Rn[0, 2] ** 2)
        r1 = Rn[1] - (r0 @ Rn[1]) * r0
        r1 = r1 / np.sqrt(r1[0] ** 2 + r1[1] ** 2 + r1[2] ** 2)
        r2 = np.cross(r0, r1)
        R[i, 0] = r0
        R[i, 1] = r1
        R[i, 2] = r2
