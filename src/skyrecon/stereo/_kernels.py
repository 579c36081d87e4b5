"""Numba kernels of the skyrecon semi-global matcher.

Every kernel is compiled for one set of argument types (``cache=True`` keeps the machine code
on disk), so a process pays the JIT cost once and the frames of a sequence never recompile.
``sgm_band`` is specialised once per number of paths per sweep (1, 2 or 3).

Data layout (``wp`` = image width rounded up to a multiple of 32 lanes):

- grey images: (H, W) uint8; census codes: (rows, wp) uint32 (right codes padded left and
  right so that shifted vector reads stay inside the buffer);
- path states: per path, (D + 2, wp + 2) int16 planes, padded with BIG at both disparity ends
  and with restart columns at both image ends;
- the upward sweep's path sums: (rows, D * wp) uint8 block-major (32-column blocks of D
  planes), saturated at 255;
- the total cost of the row being selected: (D + 4, wp) uint16 row-major;
- the optional horizontal paths (``_horizontal_paths``): per row, uint8 x-major (column x,
  plane order reversed) costs, left-to-right path costs and the two paths' sums, whose 32x32
  tiles are transposed into the upward sweep's block-major sums.

Plane index ``k`` means disparity ``d = dmin + k`` (``x_right = x_left - d``).

Performance: the hot loops are written as LLVM vector IR (``@intrinsic``, 32 int16 lanes over
image columns): the disparity loop of one 32-column block keeps the previous pixel's costs at
d - 1, d, d + 1 in registers and computes the census Hamming cost in registers (VPOPCNTD on
AVX-512, a shuffle-based popcount on AVX2), so each plane costs one state load and one store
per path. Plain Numba loops are used where LLVM's auto-vectoriser does well (contiguous 1-D
slices; indexing a flat array with a computed offset defeats it, since numba's negative-index
wrap-around becomes a select).
"""

from __future__ import annotations

from typing import Any

import llvmlite.ir as ir  # type: ignore[import-untyped]  # llvmlite ships no type information
import numpy as np
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

_JIT: dict[str, Any] = dict(cache=True, nogil=True, boundscheck=False, error_model="numpy")

BIG = 30000  # "infinite" path cost that still fits int16 arithmetic
INVALID_RIGHT = -(1 << 20)


LANES = 32  # int16 lanes per explicit vector (one AVX-512 register, two AVX2 registers)

_I8 = ir.IntType(8)
_I16 = ir.IntType(16)
_I64 = ir.IntType(64)
_V16 = ir.VectorType(_I16, LANES)
_V8 = ir.VectorType(_I8, LANES)


def _data(context, builder, aty, val):
    return context.make_array(aty)(context, builder, val).data


def _vload(builder, base, idx, vty):
    return builder.load(builder.bitcast(builder.gep(base, [idx]), vty.as_pointer()), align=1)


def _vstore(builder, val, base, idx):
    builder.store(val, builder.bitcast(builder.gep(base, [idx]), val.type.as_pointer()), align=1)


def _splat(builder, scalar, vty):
    undef = ir.Constant(vty, ir.Undefined)
    v = builder.insert_element(undef, scalar, ir.Constant(ir.IntType(32), 0))
    mask = ir.Constant(ir.VectorType(ir.IntType(32), vty.count), [0] * vty.count)
    return builder.shuffle_vector(v, undef, mask)


def _smin(builder, a, b):
    return builder.select(builder.icmp_signed("<", a, b), a, b)


def _ucmp_min(builder, a, b):
    return builder.select(builder.icmp_unsigned("<", a, b), a, b)


def _i64(builder, v):
    return v if v.type.width == 64 else builder.sext(v, _I64)


_I32 = ir.IntType(32)
_V32 = ir.VectorType(_I32, LANES)


def _vctpop(builder, v):
    fnty = ir.FunctionType(v.type, [v.type])
    fn = cgutils.get_or_insert_function(builder.module, fnty, f"llvm.ctpop.v{LANES}i32")
    return builder.call(fn, [v])


@intrinsic
def _sweep_block(
    typingctx,
    cl,
    cr,
    cr_pad,
    dmin,
    W,
    oc,
    x0,
    wp,
    st_prev,
    st_cur,
    offsets,
    Q,
    M,
    min_cur,
    P1,
    D,
    s_out,
    s_base,
    s_ks,
    other,
    o_base,
    o_ks,
    select,
    sel_out,
):
    """SGM recursion of every path of a sweep for the 32 columns ``x0 .. x0 + 31`` of one row.

    Explicit 32-lane int16 vectors; the disparity loop keeps the previous pixel's costs at
    d - 1, d, d + 1 in registers (one new load per disparity and path).

    The matching cost of plane k (disparity ``d = dmin + k``) is computed in registers:
    ``popcount(cl[x] ^ cr[cr_pad + x - d])`` for ``0 <= x - d < W`` and ``x < W``, else ``oc``.
    ``cl`` (wp,) and ``cr`` (cr_pad + wp + pad,) are uint32 census rows; ``cr`` is padded so
    that every read stays inside it.

    Flat C-ordered buffers (``wp`` = padded width, a multiple of 32; ``n`` = len(offsets)):
        st_prev, st_cur (n, D + 2, wp + 2) int16 path states (disparity
        rows 0 and D + 1 hold BIG, column c holds pixel c - 1); Q, M (n, wp) int16
        ``min_prev + P2`` and ``min_prev`` of each pixel's predecessor; min_cur (n, wp + 2)
        int16 receives the new minima.
    Output, plane k of this block at ``s_out[s_base + k * s_ks + lane]``:
        without ``select``, the sum of the paths (uint16, or uint8 saturated at 255); with
        ``select``, that sum plus the other sweep's ``other[o_base + k * o_ks + lane]`` (uint8
        or uint16), into a uint16 ``s_out`` (0xFFFF in the lanes of columns ``>= W``), and
        the winner-takes-all state of the total goes to rows 0 and 1 of ``sel_out`` (4, wp)
        uint16 at column x0: the minimum and its plane (lowest on ties).
    """
    if not isinstance(offsets, types.UniTuple):
        return None
    n = offsets.count
    sig = types.void(
        cl,
        cr,
        cr_pad,
        dmin,
        W,
        oc,
        x0,
        wp,
        st_prev,
        st_cur,
        offsets,
        Q,
        M,
        min_cur,
        P1,
        D,
        s_out,
        s_base,
        s_ks,
        other,
        o_base,
        o_ks,
        select,
        sel_out,
    )

    def codegen(context, builder, signature, args):
        (
            cl_v,
            cr_v,
            crp_v,
            dmin_v,
            w_v,
            oc_v,
            x0_v,
            wp_v,
            sp_v,
            sc_v,
            off_v,
            q_v,
            m_v,
            mn_v,
            p1_v,
            d_v,
            so_v,
            sb_v,
            sks_v,
            ot_v,
            ob_v,
            oks_v,
            sel_v,
            selo_v,
        ) = args
        t = signature.args
        clp = _data(context, builder, t[0], cl_v)
        crp = _data(context, builder, t[1], cr_v)
        pp = _data(context, builder, t[8], sp_v)
        cu = _data(context, builder, t[9], sc_v)
        st_u8 = t[8].dtype == types.uint8  # path states stored in 8 bits (computed in 16)

        def st_load(idx):
            if st_u8:
                return builder.zext(_vload(builder, pp, idx, _V8), _V16)
            return _vload(builder, pp, idx, _V16)

        qp = _data(context, builder, t[11], q_v)
        mp = _data(context, builder, t[12], m_v)
        mnp = _data(context, builder, t[13], mn_v)
        sop = _data(context, builder, t[16], so_v)
        otp = _data(context, builder, t[19], ot_v)
        selp = _data(context, builder, t[23], selo_v)
        out_u8 = t[16].dtype == types.uint8
        other_u8 = t[19].dtype == types.uint8
        x0 = _i64(builder, x0_v)
        dmin = _i64(builder, dmin_v)
        cr_base = builder.add(builder.sub(_i64(builder, crp_v), dmin), x0)  # cr index of lane 0, plane 0
        left_codes = _vload(builder, clp, x0, _V32)
        lanes32 = ir.Constant(_V32, list(range(LANES)))
        xv = builder.add(_splat(builder, builder.trunc(x0, _I32), _V32), lanes32)  # column of each lane
        Wv = _splat(builder, builder.trunc(_i64(builder, w_v), _I32), _V32)
        in_img = builder.icmp_signed("<", xv, Wv)
        ocv = _splat(builder, builder.trunc(_i64(builder, oc_v), _I16), _V16)
        zero32 = ir.Constant(_V32, [0] * LANES)
        wp = _i64(builder, wp_v)
        D = _i64(builder, d_v)
        s_base = _i64(builder, sb_v)
        s_ks = _i64(builder, sks_v)
        o_base = _i64(builder, ob_v)
        o_ks = _i64(builder, oks_v)
        one = ir.Constant(_I64, 1)
        two = ir.Constant(_I64, 2)
        ks = builder.add(wp, two)  # state row stride
        ps = builder.mul(builder.add(D, two), ks)  # state path stride
        p1 = _splat(builder, builder.trunc(p1_v, _I16) if p1_v.type.width > 16 else p1_v, _V16)
        MAXV = ir.Constant(_V16, [0xFFFF] * LANES)
        Qs, Ms, base_prev, base_cur, am_s, ac_s, mn_s = [], [], [], [], [], [], []
        for p in range(n):
            off = builder.extract_value(off_v, p)
            row = builder.add(builder.mul(ir.Constant(_I64, p), wp), x0)
            Qs.append(_vload(builder, qp, row, _V16))
            Ms.append(_vload(builder, mp, row, _V16))
            bp = builder.add(builder.add(builder.mul(ir.Constant(_I64, p), ps), x0), builder.add(one, off))
            bc = builder.add(builder.add(builder.mul(ir.Constant(_I64, p), ps), x0), one)
            base_prev.append(bp)
            base_cur.append(bc)
            a = cgutils.alloca_once(builder, _V16)
            b = cgutils.alloca_once(builder, _V16)
            m = cgutils.alloca_once(builder, _V16)
            builder.store(st_load(bp), a)
            builder.store(st_load(builder.add(bp, ks)), b)
            builder.store(ir.Constant(_V16, [BIG] * LANES), m)
            am_s.append(a)
            ac_s.append(b)
            mn_s.append(m)

        def path_step(k):
            right_codes = _vload(builder, crp, builder.sub(cr_base, k), _V32)
            pc = builder.trunc(_vctpop(builder, builder.xor(left_codes, right_codes)), _V16)
            xr = builder.sub(xv, _splat(builder, builder.trunc(builder.add(dmin, k), _I32), _V32))  # x - d
            ok = builder.and_(
                in_img, builder.and_(builder.icmp_signed(">=", xr, zero32), builder.icmp_signed("<", xr, Wv))
            )
            c = builder.select(ok, pc, ocv)
            total = None
            for p in range(n):
                am = builder.load(am_s[p])
                ac = builder.load(ac_s[p])
                ap = st_load(builder.add(base_prev[p], builder.mul(builder.add(k, two), ks)))
                tt = builder.add(_smin(builder, am, ap), p1)
                tt = _smin(builder, _smin(builder, ac, tt), Qs[p])
                v = builder.sub(builder.add(c, tt), Ms[p])
                _vstore(
                    builder,
                    builder.trunc(v, _V8) if st_u8 else v,
                    cu,
                    builder.add(base_cur[p], builder.mul(builder.add(k, one), ks)),
                )
                builder.store(_smin(builder, builder.load(mn_s[p]), v), mn_s[p])
                builder.store(ac, am_s[p])
                builder.store(ap, ac_s[p])
                total = v if total is None else builder.add(total, v)
            return total

        selb = builder.icmp_signed("!=", sel_v, ir.Constant(sel_v.type, 0))
        with builder.if_else(selb) as (then, otherwise):
            with then:
                best_s = cgutils.alloca_once(builder, _V16)
                arg_s = cgutils.alloca_once(builder, _V16)
                builder.store(MAXV, best_s)
                builder.store(ir.Constant(_V16, [0] * LANES), arg_s)
                with cgutils.for_range(builder, D) as loop:
                    k = loop.index
                    oidx = builder.add(o_base, builder.mul(k, o_ks))
                    if other_u8:
                        oval = builder.zext(_vload(builder, otp, oidx, _V8), _V16)
                    else:
                        oval = _vload(builder, otp, oidx, _V16)
                    tot = builder.add(path_step(k), oval)
                    # columns beyond the image hold 0xFFFF: the right view's search skips them
                    _vstore(
                        builder,
                        builder.select(in_img, tot, MAXV),
                        sop,
                        builder.add(s_base, builder.mul(k, s_ks)),
                    )
                    best = builder.load(best_s)
                    lt = builder.icmp_unsigned("<", tot, best)
                    builder.store(builder.select(lt, tot, best), best_s)
                    kv = _splat(builder, builder.trunc(k, _I16), _V16)
                    builder.store(builder.select(lt, kv, builder.load(arg_s)), arg_s)
                for i, val in enumerate((builder.load(best_s), builder.load(arg_s))):
                    _vstore(builder, val, selp, builder.add(builder.mul(ir.Constant(_I64, i), wp), x0))
            with otherwise:
                with cgutils.for_range(builder, D) as loop:
                    k = loop.index
                    val = path_step(k)
                    if out_u8:  # saturate at 255: only costs near the minimum matter
                        val = builder.trunc(_ucmp_min(builder, val, ir.Constant(_V16, [255] * LANES)), _V8)
                    _vstore(builder, val, sop, builder.add(s_base, builder.mul(k, s_ks)))
        for p in range(n):
            idx = builder.add(builder.add(builder.mul(ir.Constant(_I64, p), builder.add(wp, two)), x0), one)
            _vstore(builder, builder.load(mn_s[p]), mnp, idx)
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def _select_block_second(typingctx, Sa, base, ts, D, x0, arg, second):
    """For the 32 columns ``x0 ..``: the minimum of ``Sa`` over planes not adjacent to ``arg``
    (the uniqueness test's runner-up). Element (k, x) at ``base + k * ts + x``."""
    sig = types.void(Sa, base, ts, D, x0, arg, second)

    def codegen(context, builder, signature, args):
        (a_v, base_v, ts_v, d_v, x0_v, arg_v, sec_v) = args
        t = signature.args
        ap = _data(context, builder, t[0], a_v)
        argp = _data(context, builder, t[5], arg_v)
        secp = _data(context, builder, t[6], sec_v)
        x0 = _i64(builder, x0_v)
        base = builder.add(_i64(builder, base_v), x0)
        ts = _i64(builder, ts_v)
        MAXV = ir.Constant(_V16, [0xFFFF] * LANES)
        one = _splat(builder, ir.Constant(_I16, 1), _V16)
        arg = _vload(builder, argp, x0, _V16)
        sec = cgutils.alloca_once(builder, _V16)
        builder.store(MAXV, sec)
        with cgutils.for_range(builder, _i64(builder, d_v)) as loop:
            k = loop.index
            idx = builder.add(base, builder.mul(k, ts))
            tt = _vload(builder, ap, idx, _V16)
            dist = builder.sub(_splat(builder, builder.trunc(k, _I16), _V16), arg)
            far = builder.or_(
                builder.icmp_signed(">", dist, one), builder.icmp_signed("<", dist, builder.neg(one))
            )
            builder.store(_ucmp_min(builder, builder.load(sec), builder.select(far, tt, MAXV)), sec)
        _vstore(builder, builder.load(sec), secp, x0)
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def _select_block_right(typingctx, Sa, base, ts, D, xr0, dmin, rbest, rarg):
    """Right-view winner-takes-all for the right pixels ``xr0 .. xr0 + 31`` of one row.

    The right pixel xr sees, on plane k, the left pixel ``x = xr + dmin + k``, whose cost
    ``Sa`` holds at ``base + k * ts + x`` (a diagonal of the (k, x) buffer of row stride ts).
    Planes where x falls outside the image must read 0xFFFF there (the buffer's padding: see
    ``total_stride``). Writes ``rbest`` and ``rarg`` (0xFFFF when no plane is valid) at
    ``xr0 ..``.
    """
    sig = types.void(Sa, base, ts, D, xr0, dmin, rbest, rarg)

    def codegen(context, builder, signature, args):
        (a_v, base_v, ts_v, d_v, xr0_v, dmin_v, rb_v, ra_v) = args
        t = signature.args
        ap = _data(context, builder, t[0], a_v)
        rbp = _data(context, builder, t[6], rb_v)
        rap = _data(context, builder, t[7], ra_v)
        ts = _i64(builder, ts_v)
        D = _i64(builder, d_v)
        xr0 = _i64(builder, xr0_v)
        x_first = builder.add(xr0, _i64(builder, dmin_v))  # left x of lane 0 on plane 0
        base = builder.add(_i64(builder, base_v), x_first)
        step = builder.add(ts, ir.Constant(_I64, 1))
        MAXV = ir.Constant(_V16, [0xFFFF] * LANES)
        best_s = cgutils.alloca_once(builder, _V16)
        arg_s = cgutils.alloca_once(builder, _V16)
        builder.store(MAXV, best_s)
        builder.store(MAXV, arg_s)
        with cgutils.for_range(builder, D) as loop:
            k = loop.index
            tt = _vload(builder, ap, builder.add(base, builder.mul(k, step)), _V16)
            best = builder.load(best_s)
            lt = builder.icmp_unsigned("<", tt, best)
            builder.store(builder.select(lt, tt, best), best_s)
            kv = _splat(builder, builder.trunc(k, _I16), _V16)
            builder.store(builder.select(lt, kv, builder.load(arg_s)), arg_s)
        _vstore(builder, builder.load(best_s), rbp, xr0)
        _vstore(builder, builder.load(arg_s), rap, xr0)
        return context.get_dummy_value()

    return sig, codegen


# --------------------------------------------------------------------------------------------
# census transform and matching cost
# --------------------------------------------------------------------------------------------
@njit(**_JIT)
def census_transform(padded, centres, rh, rw, checker, out, x_off, y0, y1, out_y0):
    """Census codes of a (2*rh+1) x (2*rw+1) window, centre excluded, at most 32 bits.

    A bit is set where the neighbour is darker than the centre's value in ``centres``: the
    image itself (the classic census), or the image less a tolerance (saturating at 0), so
    that a bit is set only where the neighbour is darker by more than the tolerance (a census
    that camera noise on a plain surface does not scramble). With ``checker`` only the
    neighbours with an even ``dx + dy`` are used (a sparse census: 31 bits for 9x7).

    Args:
        padded: (H + 2*rh, W + 2*rw) uint8 grey image with replicated borders.
        centres: the same shape, uint8: the values the neighbours are compared with.
        rh, rw: window half-height and half-width, pixels.
        checker: sample the window in a checkerboard pattern.
        out: (H, >= x_off + W) uint32 result, written at columns ``x_off .. x_off + W - 1``.
        x_off: first output column.
        y0, y1: the image rows to compute (a band, so that threads can share the work).
        out_y0: image row of ``out[0]`` (``out`` may hold a band of rows).
    """
    W = padded.shape[1] - 2 * rw
    for y in range(y0, y1):
        code = out[y - out_y0, x_off : x_off + W]
        centre = centres[y + rh, rw : rw + W]
        for x in range(W):
            code[x] = 0
        for dy in range(2 * rh + 1):
            for dx in range(2 * rw + 1):
                if dy == rh and dx == rw:
                    continue
                if checker and (dy + dx - rh - rw) % 2 != 0:
                    continue
                nb = padded[y + dy, dx : dx + W]
                for x in range(W):
                    code[x] = (code[x] << np.uint32(1)) | np.uint32(nb[x] < centre[x])


def census_bits(width: int, height: int, checker: bool) -> int:
    """Number of bits of a census code (see :func:`census_transform`)."""
    rh, rw = height // 2, width // 2
    n = 0
    for dy in range(height):
        for dx in range(width):
            if (dy, dx) == (rh, rw) or (checker and (dy + dx - rh - rw) % 2):
                continue
            n += 1
    return n


# --------------------------------------------------------------------------------------------
# semi-global aggregation
# --------------------------------------------------------------------------------------------
@njit(inline="always")
def _sweep_row(
    cl,
    cr,
    cr_pad,
    dmin,
    oc,
    D,
    W,
    grey_row,
    grey_prev,
    P1,
    P2,
    alpha,
    offsets,
    st_prev,
    st_cur,
    min_prev,
    min_cur,
    Q,
    M,
    restart,
    left_start,
    s_out,
    s_base,
    s_stride,
    other,
    o_base,
    o_block_major,
    select,
    sel_out,
):
    """Advance every path of a sweep by one image row (see ``_sweep_block`` for the outputs).

    State layout ``st[path, k + 1, x + 1]`` (flattened): disparity rows 0 and D + 1 hold BIG;
    column 0 and the columns after the last pixel hold zeros with minimum 0, which restarts
    a diagonal at the image border. ``restart`` starts every path on this row (L = C).
    The paths whose predecessor lies to the left (offset -1) also restart at pixel
    ``left_start`` (0: only at the border), as if the image began there.
    ``W`` is the real image width, ``wp`` (the length of ``cl``) the padded one. The jump
    penalty is ``max(P1 + 1, P2 / (1 + alpha * |I(p) - I(p - r)|))``. A flat cost-sum buffer
    is either block-major (block b, plane k, lane at ``base + (b * D + k) * 32 + lane``) or
    row-major (plane k, column x at ``base + k * stride + x``): ``s_stride`` 0 makes ``s_out``
    block-major, a positive one row-major with that stride (``other`` is block-major when
    ``o_block_major``, else row-major with stride ``wp``).
    """
    wp = cl.shape[0]
    n = len(offsets)
    p1p = np.float32(P1 + 1)
    p2f = np.float32(P2)
    al = np.float32(alpha)
    ps = (D + 2) * (wp + 2)
    for p in range(n):
        off = offsets[p]
        mp = min_prev[p * (wp + 2) : (p + 1) * (wp + 2)]
        qrow = Q[p * wp : (p + 1) * wp]
        mrow = M[p * wp : (p + 1) * wp]
        if restart:
            for x in range(wp):
                mrow[x] = 0
                qrow[x] = 0
            z = st_prev[p * ps : (p + 1) * ps]
            for k in range(1, D + 1):
                for x in range(wp + 2):
                    z[k * (wp + 2) + x] = 0
        else:
            for x in range(wp):
                mrow[x] = mp[x + 1 + off]
            # predecessors inside the image: x + off in [0, W)
            xa = max(0, -off)
            xb = min(W, W - off)
            g = grey_row[xa:xb]
            gp = grey_prev[xa + off : xb + off]
            mseg = mrow[xa:xb]
            qseg = qrow[xa:xb]
            for x in range(xb - xa):
                dI = np.float32(abs(np.int32(g[x]) - np.int32(gp[x])))
                qseg[x] = np.int16(mseg[x] + np.int16(max(p1p, p2f / (np.float32(1.0) + al * dI))))
            for x in range(xa):
                qrow[x] = np.int16(mrow[x] + np.int16(P2))
            for x in range(xb, wp):
                qrow[x] = np.int16(mrow[x] + np.int16(P2))
    for x0 in range(0, wp, LANES):
        if s_stride == 0:
            sb, sks = s_base + x0 * D, LANES
        else:
            sb, sks = s_base + x0, s_stride
        if o_block_major:
            ob, oks = o_base + x0 * D, LANES
        else:
            ob, oks = o_base + x0, wp
        _sweep_block(
            cl,
            cr,
            cr_pad,
            dmin,
            W,
            oc,
            x0,
            wp,
            st_prev,
            st_cur,
            offsets,
            Q,
            M,
            min_cur,
            P1,
            D,
            s_out,
            sb,
            sks,
            other,
            ob,
            oks,
            select,
            sel_out,
        )
    # columns beyond the image restart diagonals, like column 0
    for p in range(n):
        mc = min_cur[p * (wp + 2) : (p + 1) * (wp + 2)]
        mc[0] = 0
        for x in range(W + 1, wp + 2):
            mc[x] = 0
        if W < wp:
            z = st_cur[p * ps : (p + 1) * ps]
            for k in range(1, D + 1):
                for x in range(W + 1, wp + 2):
                    z[k * (wp + 2) + x] = 0
    # paths coming from the left restart at pixel left_start (its predecessor, pixel
    # left_start - 1, sits in column left_start)
    if 0 < left_start < W:
        for p in range(n):
            if offsets[p] < 0:
                min_cur[p * (wp + 2) + left_start] = 0
                z = st_cur[p * ps : (p + 1) * ps]
                for k in range(1, D + 1):
                    z[k * (wp + 2) + left_start] = 0


@njit(inline="always")
def total_stride(wp: int, dmin: int, dmax: int) -> int:
    """Row stride of the selecting sweep's (D + 4, stride) uint16 total-cost buffer: ``wp``
    plus padding of 0xFFFF wide enough that every read of the right view's diagonal search
    (left columns ``dmin - 1 .. wp - 2 + dmax``) outside ``0 .. wp - 1`` falls in padding."""
    extra = max(dmax, -dmin, 0)
    return wp + -(-extra // LANES) * LANES


@njit(inline="always")
def _select_row(total, W, dmin, uniqueness, subpixel, lr_max_diff, sel, second, rbest, rarg, disp, right):
    """Finish the disparity selection of one row: right view, uniqueness, sub-pixel, LR check.

    Args:
        total: (D + 4, ts) uint16 total costs with plane k in row k + 2 (two rows of 0xFFFF
            on each side) and 0xFFFF in the columns from ``W`` (ts: :func:`total_stride`).
        sel: (4, wp) uint16 left winner-takes-all state from the sweep (best, arg); rows 2 and
            3 receive the totals at the planes before and after the best (0xFFFF at the ends).
        second, rbest, rarg: (wp,) uint16 scratch.
        disp: (W,) float32 output, NaN where rejected; right: (W,) int32 right disparities.
    """
    D = total.shape[0] - 4
    ts = total.shape[1]
    wp = sel.shape[1]
    tf = total.reshape(-1)
    best = sel[0]
    arg = sel[1]
    cm1 = sel[2]
    cp1 = sel[3]
    for x in range(W):  # the neighbouring planes' totals (rows arg + 1 and arg + 3)
        i = (np.int64(arg[x]) + 1) * ts + x
        cm1[x] = tf[i]
        cp1[x] = tf[i + 2 * ts]
    want_second = uniqueness > 0.0
    for x0 in range(0, wp, LANES):
        _select_block_right(tf, 2 * ts, ts, D, x0, dmin, rbest, rarg)
        if want_second:
            _select_block_second(tf, 2 * ts, ts, D, x0, arg, second)
    for xr in range(W):
        r = np.int32(rarg[xr])
        right[xr] = r + dmin if r != 0xFFFF else INVALID_RIGHT
    # branch-free so that it vectorises
    half = np.float32(0.5)
    nan = np.float32(np.nan)
    for x in range(W):
        c1 = np.float32(best[x])
        c0 = np.float32(cm1[x])
        c2 = np.float32(cp1[x])
        inner = (cm1[x] != 0xFFFF) & (cp1[x] != 0xFFFF) & (subpixel > 0)
        den = c0 - np.float32(2.0) * c1 + c2 if subpixel == 1 else max(c0, c2) - c1
        den = den if den > 0 else np.float32(1.0)
        off = half * (c0 - c2) / den if inner else np.float32(0.0)
        disp[x] = np.float32(np.int32(arg[x]) + dmin) + off
    if want_second:
        for x in range(W):
            unique = np.float32(second[x]) > np.float32(best[x]) * np.float32(1.0 + uniqueness)
            disp[x] = disp[x] if unique else nan
    if lr_max_diff >= 0.0:
        lim = np.float32(lr_max_diff)
        for x in range(W):
            d = disp[x]
            dd = d if d == d else np.float32(1e6)  # NaN (rejected already) -> outside
            xr = np.int32(np.floor(np.float32(x) - dd + half))
            xc = min(max(xr, 0), W - 1)
            ok = (xr >= 0) & (xr < W) & (abs(np.float32(right[xc]) - d) <= lim)
            disp[x] = d if ok else nan


@intrinsic
def _ctpop32(typingctx, v):
    """Set bits of the low 32 bits of an integer (LLVM's ctpop, which the loop vectoriser
    turns into vector code)."""
    if not isinstance(v, types.Integer):
        return None

    def codegen(context, builder, signature, args):
        x = args[0]
        if x.type.width != 32:
            x = builder.trunc(x, _I32)
        return builder.ctpop(x)

    return types.uint32(v), codegen


def _transpose_masks() -> list[tuple[list[int], list[int]]]:
    """Shuffle masks of a 32x32 transpose in 5 stages (swap the off-diagonal h x h blocks of
    every 2h x 2h block, h = 16 .. 1): rows i and i + h (i & h == 0) become
    ``shuffle(row_i, row_ih, lo)`` and ``shuffle(row_i, row_ih, hi)``."""
    out = []
    for h in (16, 8, 4, 2, 1):
        lo = [c if c & h == 0 else LANES + c - h for c in range(LANES)]
        hi = [c + h if c & h == 0 else LANES + c for c in range(LANES)]
        out.append((lo, hi))
    return out


_TRANSPOSE_MASKS = _transpose_masks()


@intrinsic
def _add_tile_transposed(typingctx, src, src_base, src_stride, dst, dst_base, dst_step):
    """``dst[dst_base + j * dst_step + i] = sat8(dst[...] + src[src_base + i * src_stride + j])``
    for i, j in 0..31: adds the transpose of a 32x32 uint8 tile with saturation at 255.

    32 vector loads, 5 stages of 32 two-source shuffles (unpack instructions), 32 saturating
    vector adds: the horizontal paths' sums (x-major) join the block-major path sums."""
    sig = types.void(src, src_base, src_stride, dst, dst_base, dst_step)

    def codegen(context, builder, signature, args):
        src_v, sb_v, ss_v, dst_v, db_v, ds_v = args
        t = signature.args
        sp = _data(context, builder, t[0], src_v)
        dp = _data(context, builder, t[3], dst_v)
        sb, ss, db, ds = (_i64(builder, v) for v in (sb_v, ss_v, db_v, ds_v))
        rows = [
            _vload(builder, sp, builder.add(sb, builder.mul(ss, ir.Constant(_I64, i))), _V8)
            for i in range(LANES)
        ]
        mask_ty = ir.VectorType(ir.IntType(32), LANES)
        for h, (lo, hi) in zip((16, 8, 4, 2, 1), _TRANSPOSE_MASKS):
            new = list(rows)
            for i in range(LANES):
                if i & h:
                    continue
                a, b = rows[i], rows[i + h]
                new[i] = builder.shuffle_vector(a, b, ir.Constant(mask_ty, lo))
                new[i + h] = builder.shuffle_vector(a, b, ir.Constant(mask_ty, hi))
            rows = new
        fnty = ir.FunctionType(_V8, [_V8, _V8])
        sat = cgutils.get_or_insert_function(builder.module, fnty, f"llvm.uadd.sat.v{LANES}i8")
        for j in range(LANES):
            at = builder.add(db, builder.mul(ds, ir.Constant(_I64, j)))
            _vstore(builder, builder.call(sat, [_vload(builder, dp, at, _V8), rows[j]]), dp, at)
        return context.get_dummy_value()

    return sig, codegen


@njit(inline="always")
def _row_costs(cl, cr, cr_pad, dmin, oc, D, W, x, out):
    """Matching costs of pixel ``x`` of one row in reversed plane order: ``out[r]`` is plane
    ``k = D - 1 - r`` (disparity ``dmin + k``), ``popcount(cl[x] ^ cr[cr_pad + x - d])``, or
    ``oc`` where ``x - d`` falls outside ``[0, W)``. Reversed, the right codes are read
    forwards (a contiguous slice)."""
    code = cl[x]
    base = cr_pad + x - dmin - (D - 1)
    seg = cr[base : base + D]
    for r in range(D):
        out[r] = np.uint8(_ctpop32(code ^ seg[r]))
    xr0 = x - dmin - (D - 1)  # right column of r = 0
    for r in range(0, min(D, max(0, -xr0))):
        out[r] = np.uint8(oc)
    for r in range(max(0, W - xr0), D):
        out[r] = np.uint8(oc)


#: the horizontal paths run in uint8: their jump penalty is capped here, so that with census
#: costs of at most 32 every value stays below 255 (path costs <= 32 + cap, their minimum plus
#: the jump <= 32 + 2 * cap); the default P2 (100) is below it
H_MAX_JUMP = 111
#: a path state's padding at both disparity ends, less P1 (so that ``pad + P1`` cannot wrap)
_H_PAD = 255


@njit(inline="always")
def _horizontal_step(cost, prev, cur, D, m, pen, p1, fwd, sums, backward):
    """One step of a horizontal path, uint8: ``cur[1 + r] = cost[r] + min(prev[1 + r],
    prev[r] + P1, prev[2 + r] + P1, m + pen) - m`` (``prev``/``cur`` (D + 2,) with a large
    value at both ends, ``m`` the minimum of ``prev``); returns the minimum of ``cur``.
    Forward, the costs are also stored in ``fwd`` (D,); ``backward``, ``sums[r] =
    min(fwd[r] + cur[1 + r], 255)``. One loop, vectorised over the planes."""
    jump = np.uint8(m + pen)
    nm = np.uint8(255)
    if backward:
        for r in range(D):
            a = min(prev[r + 1], np.uint8(min(prev[r], prev[r + 2]) + p1))
            v = np.uint8(cost[r] + np.uint8(min(a, jump) - m))
            cur[r + 1] = v
            nm = min(nm, v)
        for r in range(D):  # a loop of its own, with a wrapping add: 3x faster than fused
            f = fwd[r]
            t = np.uint8(f + cur[r + 1])
            sums[r] = t if t >= f else np.uint8(255)
    else:
        for r in range(D):
            a = min(prev[r + 1], np.uint8(min(prev[r], prev[r + 2]) + p1))
            v = np.uint8(cost[r] + np.uint8(min(a, jump) - m))
            cur[r + 1] = v
            fwd[r] = v
            nm = min(nm, v)
    return nm


@njit(inline="always")
def _path_start(cost, state, D):
    """A horizontal path starting at a row's end: ``state[1 + r] = cost[r]``; returns the
    minimum."""
    m = np.uint8(255)
    for r in range(D):
        state[r + 1] = cost[r]
        m = min(m, cost[r])
    return m


@njit(inline="always")
def _horizontal_paths(
    cl, cr, cr_pad, dmin, oc, D, W, grey, P1, P2, alpha, fwd, prev, cur, pen, costs, sums, s_out, s_base
):  # fmt: skip
    """Add the left-to-right and right-to-left paths of one row to its block-major uint8 path
    sums ``s_out`` (plane k of column x at ``s_base + ((x // 32) * D + k) * 32 + x % 32``,
    saturated at 255).

    Plain Numba loops in uint8, vectorised over the planes, in reversed plane order (see
    ``_row_costs``; the recursion is symmetric in the plane order). All uint8: ``cl``, ``cr``
    and ``grey`` the row's census codes and grey levels, ``costs`` (wp * D,) its matching costs
    (x-major), ``fwd`` (wp * D,) its left-to-right path costs, ``prev``/``cur`` (D + 2,) path
    states, ``pen`` (wp,) the jump penalty between columns x - 1 and x, ``min(H_MAX_JUMP,
    max(P1 + 1, P2 / (1 + alpha * |I(x) - I(x - 1)|)))``, ``sums`` (wp * D,) the two paths' sum
    per column (x-major), added by 32x32 tile transposes. Needs P1 < H_MAX_JUMP.
    """
    p1 = np.uint8(P1)
    p1p = np.float32(P1 + 1)
    p2f = np.float32(P2)
    al = np.float32(alpha)
    cap = np.float32(H_MAX_JUMP)
    pad = np.uint8(_H_PAD - P1)
    wp = len(sums) // D
    for x in range(1, W):
        dI = np.float32(abs(np.int32(grey[x]) - np.int32(grey[x - 1])))
        pen[x] = np.uint8(min(cap, max(p1p, p2f / (np.float32(1.0) + al * dI))))
    for a in (prev, cur):
        a[0] = pad
        a[D + 1] = pad
    m = np.uint8(0)  # the path's last minimum
    for x in range(W):
        c = costs[x * D : (x + 1) * D]
        f = fwd[x * D : (x + 1) * D]
        _row_costs(cl, cr, cr_pad, dmin, oc, D, W, x, c)
        if x == 0:
            m = _path_start(c, prev, D)
            for r in range(D):
                f[r] = c[r]
            continue
        m = _horizontal_step(c, prev, cur, D, m, pen[x], p1, f, sums, False)
        prev, cur = cur, prev
    for x in range(W - 1, -1, -1):
        c = costs[x * D : (x + 1) * D]
        f = fwd[x * D : (x + 1) * D]
        h = sums[x * D : (x + 1) * D]
        if x == W - 1:
            m = _path_start(c, prev, D)
            for r in range(D):
                h[r] = np.uint8(min(np.uint16(f[r]) + np.uint16(c[r]), 255))
            continue
        m = _horizontal_step(c, prev, cur, D, m, pen[x + 1], p1, f, h, True)
        prev, cur = cur, prev
    for i in range(W * D, wp * D):  # padding columns add nothing
        sums[i] = 0
    tiles = D - D % LANES
    for b in range(wp // LANES):
        col = b * LANES * D
        for r0 in range(0, tiles, LANES):
            # reversed plane r0 + j is plane D - 1 - r0 - j
            _add_tile_transposed(sums, col + r0, D, s_out, s_base + (b * D + D - 1 - r0) * LANES, -LANES)
        for r in range(tiles, D):  # planes left over from whole tiles
            o = s_base + (b * D + D - 1 - r) * LANES
            for lane in range(LANES):
                i = o + lane
                v = np.int32(s_out[i]) + np.int32(sums[col + lane * D + r])
                s_out[i] = np.uint8(min(v, 255))


def band_workspace_sizes(
    D: int, wp: int, n: int, horizontal: bool = False, dmin: int = 0
) -> tuple[int, int, int, int]:
    """Elements of the path-state, int16, uint16 and uint8 workspaces ``sgm_band`` needs for D
    planes from ``dmin``, padded width wp and n paths per sweep."""
    n_state = 2 * n * (D + 2) * (wp + 2)
    n16 = 2 * n * (wp + 2) + 2 * n * wp
    n8 = D * wp
    if horizontal:  # one row's matching costs, left-to-right path costs, path sums; two path
        # states; penalties
        n8 += 3 * wp * D + 2 * (D + 2) + wp
    return n_state, n16, (D + 4) * total_stride.py_func(wp, dmin, dmin + D) + 7 * wp, n8


def states_fit_uint8(max_cost: int, P1: int, P2: float) -> bool:
    """Whether the path states of ``sgm_band`` fit 8 bits: a state is at most the matching cost
    plus the jump penalty above its predecessor's minimum (``max_cost + max(P1 + 1, P2)``).
    Stored in 8 bits, the states of a 192-plane row of 1248 pixels (two rows, two paths) take
    1 MB instead of 2 and stay in a 2 MB L2 cache: KITTI at 192 disparities 75 -> 36 ms of
    aggregation per band (identical disparities)."""
    return max_cost + max(P1 + 1, int(np.ceil(P2))) <= 255


def handoff_size(D: int, wp: int, n: int) -> int:
    """Elements of the int16 path state ``sgm_band`` hands from one band to the next (phases 1
    and 2): the states and minima of the n paths of one sweep at one row."""
    return n * (D + 2) * (wp + 2) + n * (wp + 2)


@njit(**_JIT)
def sgm_band(
    cl,
    cr,
    cr_pad,
    y_base,
    grey,
    dmin,
    out_of_image_cost,
    P1,
    P2,
    alpha,
    offsets,
    up_offsets,
    r0,
    r1,
    margin_top,
    margin_bottom,
    uniqueness,
    subpixel,
    lr_max_diff,
    horizontal,
    S_band,
    disp,
    right_out,
    ws16,
    wsu16,
    ws8,
    ws_state,
    left_start,
    phase,
    mirror,
    hand,
):
    """Semi-global matching of the image rows [r0, r1): aggregation, selection, LR check.

    Two sweeps over the band. The *storing* sweep (upward, or downward when ``mirror``) runs
    over the band and its margin on the far side, storing the sum of its paths in ``S_band``;
    the *selecting* sweep (the other direction) then adds its own paths and selects the
    disparity of each row as soon as it is complete. Paths start at the image border or
    ``margin_top`` / ``margin_bottom`` rows outside the band (warm-up), so bands run
    independently on separate threads.

    Two neighbouring bands can instead hand their path states across their common edge, so
    that neither needs a margin there and both compute exactly what one band over both would
    (up to the saturation of the stored sums at 255): the upper band mirrored, the lower one
    not, each first runs ``phase`` 1 (its storing sweep, which writes the paths' state at its
    last row to ``hand``), then, once the other band's phase 1 is done, ``phase`` 2 with the
    other band's ``hand``: its selecting sweep starts from that state at the common edge.
    ``phase`` 0 runs both sweeps at once (``hand`` unused). Matching costs (Hamming
    distances of the census codes) are computed on the fly.

    Args:
        cl: (rows, wp) uint32 left census codes of the image rows ``y_base ..``, ``wp`` = W
            rounded up to a multiple of 32; they must cover the band and its margins.
        cr: (rows, cr_pad + wp + pad) uint32 right census codes at columns ``cr_pad ..``, with
            ``cr_pad >= max(dmax, 0) + 32`` and ``pad >= max(-dmin, 0) + 32``.
        y_base: image row of ``cl[0]`` and ``cr[0]``.
        grey: (H, W) uint8 left image (edges lower the jump penalty P2).
        dmin: disparity of plane 0, pixels; the number of planes D is ``S_band.shape[1] // wp``.
        out_of_image_cost: cost of a match outside the right image.
        P1, P2, alpha: penalties: P1 for a one-pixel disparity change, and
            ``max(P1 + 1, P2 / (1 + alpha * |I(p) - I(p - r)|))`` for larger jumps.
        offsets: tuple of column offsets of the downward paths' predecessors on the row above
            (0 vertical, -1/+1 diagonals); ``up_offsets`` the same for the upward paths.
        r0, r1: the band.
        margin_top, margin_bottom: rows of warm-up above and below the band.
        uniqueness, subpixel, lr_max_diff: see ``_select_row``.
        horizontal: also aggregate along each row (left to right and right to left; their sum
            joins the storing sweep's in ``S_band``, see ``_horizontal_paths``).
        S_band: (r1 - r0, D * wp) uint8 scratch: the storing sweep's sums saturated at 255
            (each row block-major: 32-column blocks of D planes); kept from phase 1 to 2.
        disp: (H, W) float32 output (rows r0..r1-1 are written), NaN where rejected.
        right_out: (H, W) int32 integer right-view disparities (rows r0..r1-1).
        ws16, wsu16, ws8: preallocated int16 / uint16 / uint8 workspaces of at least
            :func:`band_workspace_sizes` elements (reused across frames).
        ws_state: the path states' workspace (as many elements): uint8 when
            :func:`states_fit_uint8` (half the memory traffic of the sweeps), else int16.
        left_start: the diagonal paths coming from the left restart at this column, as at
            the image border (0: only there); see ``SkyreconSettings.left_band_restart``.
        phase: 0 both sweeps; 1 the storing sweep (and the horizontal paths); 2 the selecting
            sweep, from ``hand``.
        mirror: store downward and select upward (the upper band of a pair).
        hand: (handoff_size,) int16: written by phase 1, read by phase 2 (empty for phase 0).
    """
    H, W = grey.shape
    wp = cl.shape[1]
    D = S_band.shape[1] // wp
    n = len(offsets)
    P1 = np.int16(P1)
    n_st = 2 * n * (D + 2) * (wp + 2)
    n_state = n * (D + 2) * (wp + 2)
    st = ws_state[:n_st].reshape((2, n_state))
    big = min(np.iinfo(ws_state.dtype).max, BIG)
    mins = ws16[: 2 * n * (wp + 2)].reshape((2, n * (wp + 2)))
    o = 2 * n * (wp + 2)
    Q = ws16[o : o + n * wp]
    M = ws16[o + n * wp : o + 2 * n * wp]
    hs = wp * D if horizontal else 0  # the horizontal paths' uint8 buffers (none when off)
    hd = D + 2 if horizontal else 0
    o8 = D * wp
    h_costs = ws8[o8 : o8 + hs]
    h_fwd = ws8[o8 + hs : o8 + 2 * hs]
    h_sums = ws8[o8 + 2 * hs : o8 + 3 * hs]
    o8 += 3 * hs
    h_prev = ws8[o8 : o8 + hd]
    h_cur = ws8[o8 + hd : o8 + 2 * hd]
    h_pen = ws8[o8 + 2 * hd : o8 + 2 * hd + (wp if horizontal else 0)]
    st[:] = 0
    mins[:] = 0
    for a in range(2):
        for p in range(n):
            base = p * (D + 2) * (wp + 2)
            for x in range(wp + 2):
                st[a, base + x] = big
                st[a, base + (D + 1) * (wp + 2) + x] = big
    ts = total_stride(wp, dmin, dmin + D)
    nt = (D + 4) * ts
    total = wsu16[:nt].reshape((D + 4, ts))
    total[:] = 0xFFFF
    sel = wsu16[nt : nt + 4 * wp].reshape((4, wp))
    second = wsu16[nt + 4 * wp : nt + 5 * wp]
    rbest = wsu16[nt + 5 * wp : nt + 6 * wp]
    rarg = wsu16[nt + 6 * wp : nt + 7 * wp]
    scratch8 = ws8[: D * wp]
    oc = np.int64(out_of_image_cost)
    band_flat = S_band.reshape(-1)
    row_len = D * wp
    # the storing sweep's paths, rows and direction; the selecting sweep's are the others
    store_offsets = offsets if mirror else up_offsets
    select_offsets = up_offsets if mirror else offsets
    store_step = 1 if mirror else -1

    if phase != 2:  # the storing sweep: the sum of its paths goes to S_band (block-major rows)
        ystart = max(0, r0 - margin_top) if mirror else min(H, r1 + margin_bottom) - 1
        yend = r1 if mirror else r0 - 1
        par = 0
        for y in range(ystart, yend, store_step):
            inside = y >= r0 and y < r1
            _sweep_row(
                cl[y - y_base],
                cr[y - y_base],
                cr_pad,
                dmin,
                oc,
                D,
                W,
                grey[y],
                grey[min(max(y - store_step, 0), H - 1)],
                P1,
                P2,
                alpha,
                store_offsets,
                st[par],
                st[1 - par],
                mins[par],
                mins[1 - par],
                Q,
                M,
                y == ystart,
                left_start,
                band_flat if inside else scratch8,
                (y - r0) * row_len if inside else 0,
                0,
                scratch8,
                0,
                True,
                False,
                sel,
            )
            par = 1 - par
        if horizontal:
            for y in range(r0, r1):
                _horizontal_paths(
                    cl[y - y_base],
                    cr[y - y_base],
                    cr_pad,
                    dmin,
                    oc,
                    D,
                    W,
                    grey[y],
                    P1,
                    P2,
                    alpha,
                    h_fwd,
                    h_prev,
                    h_cur,
                    h_pen,
                    h_costs,
                    h_sums,
                    band_flat,
                    (y - r0) * row_len,
                )
        if phase == 1:  # the paths' state at the band's last row, for the next band
            hand[:n_state] = st[par]
            hand[n_state : n_state + n * (wp + 2)] = mins[par]
            return
    # the selecting sweep: total = its paths + S_band, winner-takes-all on the fly
    select_step = -store_step
    if phase == 2:  # continue the other band's paths across the common edge
        ystart = r1 - 1 if mirror else r0
        st[0] = hand[:n_state]
        mins[0] = hand[n_state : n_state + n * (wp + 2)]
    else:
        ystart = min(H, r1 + margin_bottom) - 1 if mirror else max(0, r0 - margin_top)
    yend = r0 - 1 if mirror else r1
    par = 0
    for y in range(ystart, yend, select_step):
        inside = y >= r0 and y < r1
        _sweep_row(
            cl[y - y_base],
            cr[y - y_base],
            cr_pad,
            dmin,
            oc,
            D,
            W,
            grey[y],
            grey[min(max(y - select_step, 0), H - 1)],
            P1,
            P2,
            alpha,
            select_offsets,
            st[par],
            st[1 - par],
            mins[par],
            mins[1 - par],
            Q,
            M,
            phase != 2 and y == ystart,
            left_start,
            total.reshape(-1),
            2 * ts,
            ts,
            band_flat if inside else scratch8,
            (y - r0) * row_len if inside else 0,
            True,
            inside,
            sel,
        )
        par = 1 - par
        if inside:
            _select_row(
                total,
                W,
                dmin,
                uniqueness,
                subpixel,
                lr_max_diff,
                sel,
                second,
                rbest,
                rarg,
                disp[y],
                right_out[y],
            )


INVALID16 = -32768  # "no disparity" in fixed-point maps


@njit(**_JIT)
def to_fixed(disp, scale, out, y0, y1):
    """float32 disparity (NaN invalid) -> int16 ``round(d * scale)`` (INVALID16 invalid)."""
    W = disp.shape[1]
    for y in range(y0, y1):
        src = disp[y]
        dst = out[y]
        for x in range(W):
            v = src[x]
            dst[x] = np.int16(np.floor(v * scale + 0.5)) if v == v else np.int16(INVALID16)


@njit(**_JIT)
def from_fixed(fixed, keep, inv_scale, out, y0, y1):
    """int16 fixed-point disparity -> float32 ``value * inv_scale``; NaN where INVALID16 or,
    when ``keep`` has rows, where ``keep`` is 0."""
    W = fixed.shape[1]
    use_keep = keep.shape[0] > 0
    for y in range(y0, y1):
        src = fixed[y]
        dst = out[y]
        for x in range(W):
            v = src[x]
            ok = v != INVALID16
            if use_keep:
                ok = ok and keep[y, x] != INVALID16
            dst[x] = np.float32(v) * inv_scale if ok else np.float32(np.nan)


FILL_SPAN = 48  # pixels of a row's valid side used to fit the line a fill continues
FILL_MAX_SLOPE = 0.3  # steepest continued slope, pixels of disparity per pixel
#: a row's invalid run whose left side is nearer than its right side by more than this
#: (pixels of disparity) takes the left side (see _fill_rows): on the benchmark pairs this
#: lowered the error of KITTI 0.300 -> 0.279 (192 disparities 0.205 -> 0.179) and of the
#: FlyingThings-style pairs by up to 0.04 of OpenCV's (flying-3 0.597 -> 0.559), Cones equal
FILL_NEARER_LEFT_PX = 1.0


@njit(inline="always")
def _fill_rows(disp, out, y0, y1, invalid, unit, lo, span, max_slope, rounded, nearer_left_px):
    """Fill the invalid runs of rows ``y0 .. y1 - 1`` of ``disp`` into ``out`` (same dtype).

    A run takes the surface of its farther (smaller) bounding value, continued into the run:
    occlusions belong to the background, and the background is often slanted. But in the
    left view an occlusion lies left of a nearer surface: a run whose left side is nearer
    than its right side by more than ``nearer_left_px`` pixels is no occlusion (a mismatch
    at the far edge of a nearer surface, or inside it) and takes its left side (inf: never;
    rows of a left view use FILL_NEARER_LEFT_PX). The line is a
    least-squares fit to the valid pixels among the ``span`` pixels beyond the run on that
    side (stopping at the first value farther than ``2 + j / 4`` px from the bounding one,
    j pixels away; at least ``span // 2`` pixels needed, else the bounding value is kept),
    its slope clipped to ``max_slope`` px per px; the fill never rises above the nearer
    bounding value nor falls below ``lo``. Runs at a row end use their only neighbour. Pixels
    are invalid where NaN or equal to ``invalid``; ``unit`` is the value of one pixel of
    disparity (the fixed-point scale); ``rounded`` rounds the fill to integers (fixed point).
    Rows without any valid pixel stay invalid.
    """
    W = disp.shape[1]
    # the row's valid pixels, compacted (column, value): a line fit visits only those
    pos = np.empty(W, np.int64)
    val = np.empty(W, np.float32)
    for y in range(y0, y1):
        src = disp[y]
        dst = out[y]
        nv = 0
        for x in range(W):
            v = src[x]
            if v == v and v != invalid:
                pos[nv] = x
                val[nv] = np.float32(v)
                nv += 1
        x = 0
        k = 0  # valid pixels before column x
        while x < W:
            v = src[x]
            if v == v and v != invalid:
                dst[x] = v
                x += 1
                k += 1
                continue
            x0 = x
            while x < W and not (src[x] == src[x] and src[x] != invalid):
                x += 1
            has_a = x0 > 0
            has_b = x < W
            if not (has_a or has_b):
                for xx in range(x0, x):
                    dst[xx] = invalid
                continue
            a = np.float32(src[x0 - 1]) if has_a else np.float32(0.0)
            b = np.float32(src[x]) if has_b else np.float32(0.0)
            if has_a and (not has_b or a <= b or a > b + nearer_left_px * unit):
                side, bx, base, kk = -1, x0 - 1, a, k - 1
            else:
                side, bx, base, kk = 1, x, b, k
            lim = max(a, b) if (has_a and has_b) else np.float32(np.inf)
            slope = np.float32(0.0)
            icpt = base
            sx = sy = sxx = sxy = np.float32(0.0)
            cnt = 0
            while kk >= 0 and kk < nv:
                j = (pos[kk] - bx) * side
                if j >= span:
                    break
                fv = val[kk]
                if abs(fv - base) > (np.float32(2.0) + np.float32(0.25) * j) * unit:
                    break
                fj = np.float32(j)
                sx += fj
                sy += fv
                sxx += fj * fj
                sxy += fj * fv
                cnt += 1
                kk += side
            if cnt >= span // 2:
                den = cnt * sxx - sx * sx
                if den > 0:
                    sl = (cnt * sxy - sx * sy) / den  # change per pixel away from the run
                    icpt = (sy - sl * sx) / cnt
                    slope = min(max(-sl, -max_slope), max_slope)
            for xx in range(x0, x):
                f = min(max(icpt + slope * np.float32(abs(xx - bx)), lo), lim)
                dst[xx] = np.floor(f + np.float32(0.5)) if rounded else f


@njit(**_JIT)
def fill_background_fixed(disp, out, y0, y1, unit, lo, span, max_slope, nearer_left_px):
    """:func:`_fill_rows` on an int16 fixed-point map (INVALID16 invalid, ``unit`` = scale,
    ``lo`` the smallest fill value in fixed point)."""
    _fill_rows(
        disp,
        out,
        y0,
        y1,
        np.int16(INVALID16),
        np.float32(unit),
        np.float32(lo),
        span,
        np.float32(max_slope),
        True,
        np.float32(nearer_left_px),
    )


@njit(**_JIT)
def fill_background(disp, out, y0, y1, lo, span, max_slope, nearer_left_px):
    """:func:`_fill_rows` on a float32 map (NaN invalid, ``lo`` the smallest fill value)."""
    _fill_rows(
        disp,
        out,
        y0,
        y1,
        np.float32(np.nan),
        np.float32(1.0),
        np.float32(lo),
        span,
        np.float32(max_slope),
        False,
        np.float32(nearer_left_px),
    )


# --------------------------------------------------------------------------------------------
# guided fill: the invalid pixels between the two sides of a depth edge
# --------------------------------------------------------------------------------------------
# A row fill (fill_background_fixed) can only guess "the farther side" for an invalid run
# between two depths, which fails when both sides are foreground (a background strip
# occluded between two objects) or the farther side is an outlier. The guided fill refills
# such pixels from the first valid pixel in each of 8 directions, weighted by how much its
# (smoothed) left-image colour resembles the pixel's and by its distance: a weighted median,
# without candidates nearer than the row fill (occluded pixels belong to the background).
# Three steps: guided_fill_targets, guided_fill_candidates (per direction), guided_fill_median.

# search directions of the guided fill: (dy, dx) towards the 8 neighbours
GUIDE_DY = np.array([0, 0, 1, -1, 1, 1, -1, -1], np.int64)
GUIDE_DX = np.array([1, -1, 0, 0, 1, -1, 1, -1], np.int64)


@njit(**_JIT)
def guided_fill_targets(measured, row_filled, out, unit, gate, rowptr, y0, y1):
    """First step of the guided fill: ``out`` = the measured map with the row fill in its
    holes; finds the invalid pixels whose row neighbours (the nearest valid pixels left and
    right) differ by more than ``gate`` pixels (a depth edge).

    Half of them, a checkerboard (``x + y`` even), are refilled from their candidates; the
    others then take the smallest refilled 4-neighbour (:func:`guided_fill_spread`).

    Args:
        measured: (H, W) int16 fixed-point disparity, INVALID16 where rejected.
        row_filled: (H, W) int16 the row fill of ``measured`` (:func:`fill_background_fixed`).
        out: (H, W) int16 result.
        unit: fixed-point value of one pixel of disparity; gate: pixels.
        rowptr: (H + 1,) int64 result: the computed targets of row y are
            ``rowptr[y] .. rowptr[y + 1] - 1``; written for rows ``y0 .. y1 - 1`` counting
            from 0 at row y0 (threads take disjoint ranges of rows; the caller offsets the
            later ranges and sets ``rowptr[H]``).
        y0, y1: the rows done.
    Returns:
        ((G,) int64 flat indices of the computed targets of the rows, ascending;
        (G2,) int64 flat indices of the other targets).
    """
    H, W = measured.shape
    gate_f = np.float32(gate * unit)
    right_v = np.empty(W, np.int16)
    idx = np.empty((y1 - y0) * W, np.int64)
    odd = np.empty((y1 - y0) * W, np.int64)
    G = 0
    G2 = 0
    for y in range(y0, y1):
        rowptr[y] = G
        src = measured[y]
        rf = row_filled[y]
        dst = out[y]
        last = np.int16(INVALID16)
        for x in range(W - 1, -1, -1):
            if src[x] != INVALID16:
                last = src[x]
            right_v[x] = last
        left = np.int16(INVALID16)
        for x in range(W):
            v = src[x]
            dst[x] = v if v != INVALID16 else rf[x]
            if v != INVALID16:
                left = v
                continue
            b = right_v[x]
            if left == INVALID16 or b == INVALID16 or rf[x] == INVALID16:
                continue
            if abs(np.float32(left) - np.float32(b)) > gate_f:
                if (x + y) % 2 == 0:
                    idx[G] = y * W + x
                    G += 1
                else:
                    odd[G2] = y * W + x
                    G2 += 1
    return idx[:G].copy(), odd[:G2].copy()


@njit(inline="always")
def _guided_row_candidates(
    measured, row_filled, guide, targets, rowptr, y, k, one, max_steps, w_guide, w_steps, nsteps, cv, cw
):
    """Candidate k of the targets of row y (see :func:`guided_fill_candidates`)."""
    W = measured.shape[1]
    C = guide.shape[2]
    dy = GUIDE_DY[k]
    dx = GUIDE_DX[k]
    ns = nsteps[y]
    vk = cv[k]
    wk = cw[k]
    for g in range(rowptr[y], rowptr[y + 1]):
        x = targets[g] - y * W
        vk[g] = np.float32(0.0)
        wk[g] = np.float32(0.0)
        st = np.int64(ns[x])
        if st > max_steps:
            continue
        fy = y + dy * st
        fx = x + dx * st
        u = np.float32(measured[fy, fx])
        if u > np.float32(row_filled[y, x]) + one:
            continue
        c = 0
        for ch in range(C):
            c += abs(np.int32(guide[y, x, ch]) - np.int32(guide[fy, fx, ch]))
        vk[g] = u
        wk[g] = w_guide[c] * w_steps[st]


@njit(**_JIT)
def guided_fill_candidates(
    measured, row_filled, guide, targets, rowptr, k0, k1, unit, sigma, decay, max_steps, nsteps, cv, cw
):
    """Second step of the guided fill, directions ``k0 .. k1 - 1`` (threads take disjoint
    ranges): for each target pixel, the first valid pixel along direction k (at most
    ``max_steps`` steps) is candidate k, with weight ``exp(-|guide difference| / sigma -
    decay * steps)`` (colour differences summed over channels, grey ones counted three
    times), unless it is nearer than the row fill by more than one pixel (weight 0).

    Args:
        measured, row_filled: (H, W) int16 (see :func:`guided_fill_targets`).
        guide: (H, W, C) uint8 left image (C = 1 or 3), lightly smoothed.
        targets, rowptr: the pixels to refill (:func:`guided_fill_targets`).
        nsteps: (H, W) int16 scratch (one per thread).
        cv, cw: (8, G) float32 candidate values and weights (rows k0 .. k1 - 1 written).
    """
    H, W = measured.shape
    C = guide.shape[2]
    cscale = np.float32(3.0 / C) / np.float32(sigma)
    one = np.float32(unit)
    # weight look-up tables: guide difference (integer levels) and steps
    w_guide = np.exp(-np.arange(255 * C + 1).astype(np.float32) * cscale).astype(np.float32)
    w_steps = np.exp(-np.arange(max_steps + 2).astype(np.float32) * np.float32(decay)).astype(np.float32)
    far = np.int16(max_steps + 1)  # "no valid pixel within max_steps"
    for k in range(k0, k1):
        dy = GUIDE_DY[k]
        dx = GUIDE_DX[k]
        # nsteps[y, x]: the smallest s >= 1 with (y + s dy, x + s dx) valid, or max_steps + 1.
        # Rows are done in the order the recurrence needs, and each row's targets are
        # evaluated while it is in cache.
        for i in range(H):
            y = i if dy <= 0 else H - 1 - i
            ns = nsteps[y]
            if dy == 0:  # along the row (dx = +-1): a scan
                src = measured[y]
                last = -(1 << 20)
                for j in range(W):
                    x = j if dx < 0 else W - 1 - j
                    ns[x] = np.int16(min(abs(x - last), max_steps + 1))
                    if src[x] != INVALID16:
                        last = x
            else:
                yy = y + dy
                if yy < 0 or yy >= H:
                    ns[:] = far
                else:
                    xa = max(0, -dx)
                    xb = min(W, W - dx)
                    ns[:xa] = far
                    ns[xb:] = far
                    src_s = measured[yy, xa + dx : xb + dx]
                    np_s = nsteps[yy, xa + dx : xb + dx]
                    ns_s = ns[xa:xb]
                    for x in range(xb - xa):
                        st = np.int16(1) if src_s[x] != INVALID16 else np.int16(np_s[x] + np.int16(1))
                        ns_s[x] = min(st, far)
            _guided_row_candidates(
                measured,
                row_filled,
                guide,
                targets,
                rowptr,
                y,
                k,
                one,
                max_steps,
                w_guide,
                w_steps,
                nsteps,
                cv,
                cw,
            )


@njit(**_JIT)
def guided_fill_spread(targets, done, out):
    """Last step of the guided fill: each of the other targets (not computed, see
    :func:`guided_fill_targets`) takes the smallest value among its 4-neighbours that were
    computed (``done`` 1), if any (the farther surface: the background).

    Args:
        targets: (G2,) flat indices of the pixels to set; done: (H, W) uint8; out: (H, W) int16.
    """
    H, W = out.shape
    for g in range(targets.shape[0]):
        t = targets[g]
        y = t // W
        x = t - y * W
        best = np.int32(1 << 20)
        if x > 0 and done[y, x - 1]:
            best = min(best, np.int32(out[y, x - 1]))
        if x + 1 < W and done[y, x + 1]:
            best = min(best, np.int32(out[y, x + 1]))
        if y > 0 and done[y - 1, x]:
            best = min(best, np.int32(out[y - 1, x]))
        if y + 1 < H and done[y + 1, x]:
            best = min(best, np.int32(out[y + 1, x]))
        if best < (1 << 20):
            out[y, x] = np.int16(best)


@njit(**_JIT)
def guided_fill_median(targets, cv, cw, out, g0, g1):
    """Last step of the guided fill: each target pixel of ``out`` (H, W) int16 takes the
    weighted median of its candidates ``cv``, ``cw`` (8, G) (kept as is when it has none);
    targets ``g0 .. g1 - 1`` (threads take disjoint ranges)."""
    W = out.shape[1]
    n = cv.shape[0]
    vals = np.empty(n, np.float32)
    ws = np.empty(n, np.float32)
    for g in range(g0, g1):
        m = 0
        tot = np.float32(0.0)
        for k in range(n):
            w = cw[k, g]
            if w <= 0:
                continue
            u = cv[k, g]
            i = m
            while i > 0 and vals[i - 1] > u:
                vals[i] = vals[i - 1]
                ws[i] = ws[i - 1]
                i -= 1
            vals[i] = u
            ws[i] = w
            m += 1
            tot += w
        if m == 0:
            continue
        acc = np.float32(0.0)
        for i in range(m):
            acc += ws[i]
            if acc >= np.float32(0.5) * tot:
                t = targets[g]
                y = t // W
                out[y, t - y * W] = np.int16(vals[i])
                break
