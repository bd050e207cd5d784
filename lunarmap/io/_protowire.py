"""Protocol-buffer wire format of ISIS control points, compiled with numba.

Encodes and decodes ``Isis.ControlPointFileEntryV0002`` messages (the point message of
ISIS control networks of versions 2 and 5; our own field table in
:mod:`lunarmap.io.isis_network`, written from ISIS's public ``.proto`` files) straight
between byte buffers and column arrays: one pass over a million measures takes well under
a second, where building a message object per point would take a minute.

Wire format (protobuf encoding): every field is a varint key ``field << 3 | wire type``
followed by a varint (type 0), 8 little-endian bytes (type 1), a varint length and that
many bytes (type 2: strings, packed repeated doubles, nested messages) or 4 bytes (type 5).

Strings are passed as ``(offset, length)`` into one byte buffer; length -1 = absent.
Doubles are NaN when absent; booleans are written only when true; enums and integers use
-1 for absent.
"""

from __future__ import annotations

import numpy as np

try:
    import numba
except ImportError:  # pragma: no cover - numba is a dependency
    numba = None

__all__ = ["parse_points", "count_points", "encode_points", "varint_size", "decode_varints", "hash_strings",
           "same_strings", "walk_prefixes"]


def _jit(fn):
    return numba.njit(cache=True, nogil=True)(fn) if numba is not None else fn


# -- primitives ---------------------------------------------------------------------------

@_jit
def _read_varint(buf, pos, end):
    result = np.uint64(0)
    shift = np.uint64(0)
    while True:
        if pos >= end:
            return np.uint64(0), -1
        b = buf[pos]
        pos += 1
        result |= np.uint64(b & 0x7F) << shift
        if b < 0x80:
            return result, pos
        shift += np.uint64(7)
        if shift > np.uint64(63):
            return np.uint64(0), -1


@_jit
def _read_double(buf, pos):
    v = np.uint64(0)
    for k in range(8):
        v |= np.uint64(buf[pos + k]) << np.uint64(8 * k)
    return v


@_jit
def _skip(buf, pos, end, wire):
    if wire == 0:
        _, pos = _read_varint(buf, pos, end)
        return pos
    if wire == 1:
        return pos + 8 if pos + 8 <= end else -1
    if wire == 2:
        n, pos = _read_varint(buf, pos, end)
        if pos < 0 or pos + np.int64(n) > end:
            return -1
        return pos + np.int64(n)
    if wire == 5:
        return pos + 4 if pos + 4 <= end else -1
    return -1


@_jit
def varint_size(v):
    v = np.uint64(v)
    n = 1
    while v >= np.uint64(0x80):
        v >>= np.uint64(7)
        n += 1
    return n


@_jit
def _write_varint(out, pos, v):
    v = np.uint64(v)
    while v >= np.uint64(0x80):
        out[pos] = np.uint8((v & np.uint64(0x7F)) | np.uint64(0x80))
        v >>= np.uint64(7)
        pos += 1
    out[pos] = np.uint8(v)
    return pos + 1


@_jit
def _write_double(out, pos, bits):
    for k in range(8):
        out[pos + k] = np.uint8((bits >> np.uint64(8 * k)) & np.uint64(0xFF))
    return pos + 8


# -- decoding -----------------------------------------------------------------------------

@_jit
def count_points(buf, starts, ends):
    """Measures and log entries of each point message; -1 in ``bad`` for a malformed point."""
    n = starts.size
    n_meas = np.zeros(n, np.int64)
    n_plog = np.zeros(n, np.int64)
    n_mlog = np.zeros(n, np.int64)
    bad = -1
    for i in range(n):
        pos, end = starts[i], ends[i]
        while pos < end:
            key, pos = _read_varint(buf, pos, end)
            if pos < 0:
                return n_meas, n_plog, n_mlog, i
            field, wire = np.int64(key >> np.uint64(3)), np.int64(key & np.uint64(7))
            if field == 25 and wire == 2:
                ln, pos = _read_varint(buf, pos, end)
                if pos < 0 or pos + np.int64(ln) > end:
                    return n_meas, n_plog, n_mlog, i
                mend = pos + np.int64(ln)
                n_meas[i] += 1
                while pos < mend:
                    k2, pos = _read_varint(buf, pos, mend)
                    if pos < 0:
                        return n_meas, n_plog, n_mlog, i
                    if np.int64(k2 >> np.uint64(3)) == 17 and np.int64(k2 & np.uint64(7)) == 2:
                        n_mlog[i] += 1
                    pos = _skip(buf, pos, mend, np.int64(k2 & np.uint64(7)))
                    if pos < 0:
                        return n_meas, n_plog, n_mlog, i
                continue
            if field == 24 and wire == 2:
                n_plog[i] += 1
            pos = _skip(buf, pos, end, wire)
            if pos < 0:
                return n_meas, n_plog, n_mlog, i
    return n_meas, n_plog, n_mlog, bad


@_jit
def _parse_log(buf, pos, end, row, owner, l_owner, l_dtype, l_dvalue, l_btype, l_bvalue):
    l_owner[row] = owner
    l_dtype[row] = -1
    l_dvalue[row] = np.uint64(0x7FF8000000000000)
    l_btype[row] = -1
    l_bvalue[row] = -1
    while pos < end:
        key, pos = _read_varint(buf, pos, end)
        if pos < 0:
            return False
        f, w = np.int64(key >> np.uint64(3)), np.int64(key & np.uint64(7))
        if f == 1 and w == 0:
            v, pos = _read_varint(buf, pos, end)
            l_dtype[row] = np.int64(v)
        elif f == 2 and w == 1:
            l_dvalue[row] = _read_double(buf, pos)
            pos += 8
        elif f == 3 and w == 0:
            v, pos = _read_varint(buf, pos, end)
            l_btype[row] = np.int64(v)
        elif f == 4 and w == 0:
            v, pos = _read_varint(buf, pos, end)
            l_bvalue[row] = np.int64(v != 0)
        else:
            pos = _skip(buf, pos, end, w)
        if pos < 0 or pos > end:
            return False
    return True


@_jit
def parse_points(buf, starts, ends, m_first, pl_first, ml_first, n_meas, n_plog, n_mlog):
    """Decode point messages ``buf[starts[i]:ends[i]]`` into column arrays.

    Returns the index of the first malformed point, or -1. ``*_first`` are the row of each
    point's first measure / point log / measure log (cumulative counts).
    """
    n = starts.size
    # point columns
    p_str = np.full((n, 5, 2), -1, np.int64)        # id, chooserName, datetime, surf source file, radius source file
    p_int = np.full((n, 5), -1, np.int64)           # type, referenceIndex, surf source, radius source, (spare)
    p_flag = np.zeros((n, 6), np.int8)              # editLock, ignore, jigsawRejected, lat/lon/radius constrained
    p_dbl = np.full((n, 6), np.uint64(0x7FF8000000000000), np.uint64)   # apriori xyz, adjusted xyz (bits)
    p_cov = np.full((n, 2, 6), np.uint64(0x7FF8000000000000), np.uint64)
    p_ncov = np.zeros((n, 2), np.int64)
    # measure columns
    m_str = np.full((n_meas, 3, 2), -1, np.int64)   # serialnumber, choosername, datetime
    m_type = np.full(n_meas, -1, np.int64)
    m_flag = np.zeros((n_meas, 3), np.int8)         # editLock, ignore, jigsawRejected
    m_dbl = np.full((n_meas, 9), np.uint64(0x7FF8000000000000), np.uint64)
    # sample, line, sampleResidual, lineResidual, diameter, apriorisample, aprioriline, samplesigma, linesigma
    m_point = np.zeros(n_meas, np.int64)
    pl_owner = np.zeros(n_plog, np.int64)
    pl_dtype = np.zeros(n_plog, np.int64)
    pl_dvalue = np.zeros(n_plog, np.uint64)
    pl_btype = np.zeros(n_plog, np.int64)
    pl_bvalue = np.zeros(n_plog, np.int64)
    ml_owner = np.zeros(n_mlog, np.int64)
    ml_dtype = np.zeros(n_mlog, np.int64)
    ml_dvalue = np.zeros(n_mlog, np.uint64)
    ml_btype = np.zeros(n_mlog, np.int64)
    ml_bvalue = np.zeros(n_mlog, np.int64)
    dbl_slot = np.array([-1, -1, -1, 0, 1, 2, 3, -1, -1, -1, -1, -1, 4, 5, 6, 7, 8], np.int64)
    bad = -1
    for i in range(n):
        pos, end = starts[i], ends[i]
        mrow = m_first[i]
        plrow = pl_first[i]
        mlrow = ml_first[i]
        while pos < end:
            key, pos = _read_varint(buf, pos, end)
            if pos < 0:
                return bad_result(i)
            f, w = np.int64(key >> np.uint64(3)), np.int64(key & np.uint64(7))
            if w == 2 and (f == 1 or f == 3 or f == 4 or f == 10 or f == 12):
                ln, pos = _read_varint(buf, pos, end)
                if pos < 0 or pos + np.int64(ln) > end:
                    return bad_result(i)
                slot = 0 if f == 1 else (1 if f == 3 else (2 if f == 4 else (3 if f == 10 else 4)))
                p_str[i, slot, 0] = pos
                p_str[i, slot, 1] = np.int64(ln)
                pos += np.int64(ln)
            elif w == 0 and (f == 2 or f == 8 or f == 9 or f == 11):
                v, pos = _read_varint(buf, pos, end)
                slot = 0 if f == 2 else (1 if f == 8 else (2 if f == 9 else 3))
                p_int[i, slot] = np.int64(np.int32(np.uint32(v & np.uint64(0xFFFFFFFF))))
            elif w == 0 and (f == 5 or f == 6 or f == 7 or f == 13 or f == 14 or f == 15):
                v, pos = _read_varint(buf, pos, end)
                slot = 0 if f == 5 else (1 if f == 6 else (2 if f == 7 else f - 10))
                p_flag[i, slot] = np.int8(v != 0)
            elif w == 1 and (f == 16 or f == 17 or f == 18 or f == 20 or f == 21 or f == 22):
                if pos + 8 > end:
                    return bad_result(i)
                p_dbl[i, f - 16 if f < 19 else f - 17] = _read_double(buf, pos)
                pos += 8
            elif f == 19 or f == 23:
                c = 0 if f == 19 else 1
                if w == 2:
                    ln, pos = _read_varint(buf, pos, end)
                    if pos < 0 or pos + np.int64(ln) > end or np.int64(ln) % 8 != 0:
                        return bad_result(i)
                    k = 0
                    stop = pos + np.int64(ln)
                    while pos < stop:
                        if p_ncov[i, c] < 6:
                            p_cov[i, c, p_ncov[i, c]] = _read_double(buf, pos)
                        p_ncov[i, c] += 1
                        pos += 8
                        k += 1
                elif w == 1:
                    if p_ncov[i, c] < 6:
                        p_cov[i, c, p_ncov[i, c]] = _read_double(buf, pos)
                    p_ncov[i, c] += 1
                    pos += 8
                else:
                    return bad_result(i)
            elif f == 24 and w == 2:
                ln, pos = _read_varint(buf, pos, end)
                if pos < 0 or pos + np.int64(ln) > end:
                    return bad_result(i)
                if not _parse_log(buf, pos, pos + np.int64(ln), plrow, i, pl_owner, pl_dtype, pl_dvalue,
                                  pl_btype, pl_bvalue):
                    return bad_result(i)
                plrow += 1
                pos += np.int64(ln)
            elif f == 25 and w == 2:
                ln, pos = _read_varint(buf, pos, end)
                if pos < 0 or pos + np.int64(ln) > end:
                    return bad_result(i)
                mend = pos + np.int64(ln)
                m_point[mrow] = i
                while pos < mend:
                    k2, pos = _read_varint(buf, pos, mend)
                    if pos < 0:
                        return bad_result(i)
                    g, w2 = np.int64(k2 >> np.uint64(3)), np.int64(k2 & np.uint64(7))
                    if w2 == 2 and (g == 1 or g == 7 or g == 8):
                        ln2, pos = _read_varint(buf, pos, mend)
                        if pos < 0 or pos + np.int64(ln2) > mend:
                            return bad_result(i)
                        slot = 0 if g == 1 else (1 if g == 7 else 2)
                        m_str[mrow, slot, 0] = pos
                        m_str[mrow, slot, 1] = np.int64(ln2)
                        pos += np.int64(ln2)
                    elif w2 == 0 and g == 2:
                        v, pos = _read_varint(buf, pos, mend)
                        m_type[mrow] = np.int64(v)
                    elif w2 == 0 and (g == 9 or g == 10 or g == 11):
                        v, pos = _read_varint(buf, pos, mend)
                        m_flag[mrow, g - 9] = np.int8(v != 0)
                    elif w2 == 1 and g <= 16 and dbl_slot[g] >= 0:
                        if pos + 8 > mend:
                            return bad_result(i)
                        m_dbl[mrow, dbl_slot[g]] = _read_double(buf, pos)
                        pos += 8
                    elif w2 == 2 and g == 17:
                        ln2, pos = _read_varint(buf, pos, mend)
                        if pos < 0 or pos + np.int64(ln2) > mend:
                            return bad_result(i)
                        if not _parse_log(buf, pos, pos + np.int64(ln2), mlrow, mrow, ml_owner, ml_dtype, ml_dvalue,
                                          ml_btype, ml_bvalue):
                            return bad_result(i)
                        mlrow += 1
                        pos += np.int64(ln2)
                    else:
                        pos = _skip(buf, pos, mend, w2)
                    if pos < 0 or pos > mend:
                        return bad_result(i)
                mrow += 1
            else:
                pos = _skip(buf, pos, end, w)
                if pos < 0:
                    return bad_result(i)
            if pos < 0 or pos > end:
                return bad_result(i)
    return (bad, p_str, p_int, p_flag, p_dbl, p_cov, p_ncov, m_str, m_type, m_flag, m_dbl, m_point,
            pl_owner, pl_dtype, pl_dvalue, pl_btype, pl_bvalue, ml_owner, ml_dtype, ml_dvalue, ml_btype, ml_bvalue)


@_jit
def bad_result(i):
    z2 = np.zeros((0, 0), np.int64)
    z3 = np.zeros((0, 0, 0), np.int64)
    zi = np.zeros(0, np.int64)
    zu = np.zeros(0, np.uint64)
    return (i, z3, z2, np.zeros((0, 0), np.int8), np.zeros((0, 0), np.uint64), np.zeros((0, 0, 0), np.uint64), z2,
            z3, zi, np.zeros((0, 0), np.int8), np.zeros((0, 0), np.uint64), zi,
            zi, zi, zu, zi, zi, zi, zi, zu, zi, zi)


@_jit
def decode_varints(buf, start, end):
    """The varints packed in ``buf[start:end]`` (a packed repeated int32 field); -1 on error."""
    out = np.empty(end - start, np.int64)
    n = 0
    pos = start
    while pos < end:
        v, pos = _read_varint(buf, pos, end)
        if pos < 0:
            return out[:0], -1
        out[n] = np.int64(v)
        n += 1
    return out[:n], 0


@_jit
def walk_prefixes(buf, start, end):
    """Messages each preceded by a uint32 LE size in ``buf[start:end]``: ``(starts, ends)``; end -1 if cut."""
    n = 0
    pos = start
    while pos < end:
        if pos + 4 > end:
            n += 1
            break
        size = np.int64(buf[pos]) | np.int64(buf[pos + 1]) << 8 | np.int64(buf[pos + 2]) << 16 | \
            np.int64(buf[pos + 3]) << 24
        n += 1
        pos += 4 + size
    starts = np.empty(n, np.int64)
    ends = np.empty(n, np.int64)
    pos = start
    for k in range(n):
        if pos + 4 > end:
            starts[k] = pos
            ends[k] = -1
            break
        size = np.int64(buf[pos]) | np.int64(buf[pos + 1]) << 8 | np.int64(buf[pos + 2]) << 16 | \
            np.int64(buf[pos + 3]) << 24
        starts[k] = pos + 4
        ends[k] = pos + 4 + size if pos + 4 + size <= end else -1
        pos += 4 + size
    return starts, ends


@_jit
def hash_strings(buf, off, ln):
    """64-bit FNV-1a hash of each string ``buf[off:off+ln]``; absent strings (ln < 0) hash like ''."""
    out = np.empty(off.size, np.uint64)
    for i in range(off.size):
        h = np.uint64(14695981039346656037)
        for k in range(max(ln[i], 0)):
            h = (h ^ np.uint64(buf[off[i] + k])) * np.uint64(1099511628211)
        out[i] = h
    return out


@_jit
def same_strings(buf, off, ln, ref):
    """Whether every string equals string ``ref[i]`` (its hash group's representative)."""
    for i in range(off.size):
        j = ref[i]
        a, b = max(ln[i], 0), max(ln[j], 0)
        if a != b:
            return False
        for k in range(a):
            if buf[off[i] + k] != buf[off[j] + k]:
                return False
    return True


# -- encoding -----------------------------------------------------------------------------

@_jit
def _str_size(field, ln):
    if ln < 0:
        return 0
    return varint_size(field << 3 | 2) + varint_size(ln) + ln


@_jit
def _log_size(dtype, dbits, btype, bvalue):
    s = 0
    if dtype >= 0:
        s += 1 + varint_size(dtype)
    if dbits != np.uint64(0x7FF8000000000000):
        s += 9
    if btype >= 0:
        s += 1 + varint_size(btype)
    if bvalue >= 0:
        s += 2
    return s


@_jit
def _write_log(out, pos, dtype, dbits, btype, bvalue):
    if dtype >= 0:
        out[pos] = 0x08
        pos = _write_varint(out, pos + 1, dtype)
    if dbits != np.uint64(0x7FF8000000000000):
        out[pos] = 0x11
        pos = _write_double(out, pos + 1, dbits)
    if btype >= 0:
        out[pos] = 0x18
        pos = _write_varint(out, pos + 1, btype)
    if bvalue >= 0:
        out[pos] = 0x20
        out[pos + 1] = np.uint8(bvalue)
        pos += 2
    return pos


@_jit
def _is_set(bits):
    # NaN (any payload) means absent
    return (bits & np.uint64(0x7FF0000000000000)) != np.uint64(0x7FF0000000000000) or \
        (bits & np.uint64(0x000FFFFFFFFFFFFF)) == np.uint64(0)


@_jit
def _measure_size(j, m_str, m_type, m_flag, m_dbl, ml_first, ml_count, ml_dtype, ml_dvalue, ml_btype, ml_bvalue):
    s = _str_size(1, m_str[j, 0, 1])
    s += 1 + varint_size(m_type[j])
    fields = (3, 4, 5, 6, 12, 13, 14, 15, 16)
    for k in range(9):
        if _is_set(m_dbl[j, k]):
            s += 1 + 8 if fields[k] < 16 else 2 + 8
    s += _str_size(7, m_str[j, 1, 1]) + _str_size(8, m_str[j, 2, 1])
    for k in range(3):
        if m_flag[j, k] != 0:
            s += 2
    for r in range(ml_first[j], ml_first[j] + ml_count[j]):
        ls = _log_size(ml_dtype[r], ml_dvalue[r], ml_btype[r], ml_bvalue[r])
        s += 2 + varint_size(ls) + ls
    return s


@_jit
def _write_str(out, pos, field, src, off, ln):
    if ln < 0:
        return pos
    pos = _write_varint(out, pos, field << 3 | 2)
    pos = _write_varint(out, pos, ln)
    for k in range(ln):
        out[pos + k] = src[off + k]
    return pos + ln


@_jit
def _write_measure(out, pos, j, strings, m_str, m_type, m_flag, m_dbl, ml_first, ml_count, ml_dtype, ml_dvalue,
                   ml_btype, ml_bvalue):
    pos = _write_str(out, pos, 1, strings, m_str[j, 0, 0], m_str[j, 0, 1])
    out[pos] = 0x10
    pos = _write_varint(out, pos + 1, m_type[j])
    # field order 3..16: sample, line, residuals, choosername(7), datetime(8), flags(9-11), diameter(12), ...
    for k, f in ((0, 3), (1, 4), (2, 5), (3, 6)):
        if _is_set(m_dbl[j, k]):
            pos = _write_varint(out, pos, f << 3 | 1)
            pos = _write_double(out, pos, m_dbl[j, k])
    pos = _write_str(out, pos, 7, strings, m_str[j, 1, 0], m_str[j, 1, 1])
    pos = _write_str(out, pos, 8, strings, m_str[j, 2, 0], m_str[j, 2, 1])
    for k in range(3):
        if m_flag[j, k] != 0:
            out[pos] = np.uint8((9 + k) << 3)
            out[pos + 1] = 1
            pos += 2
    for k, f in ((4, 12), (5, 13), (6, 14), (7, 15), (8, 16)):
        if _is_set(m_dbl[j, k]):
            pos = _write_varint(out, pos, f << 3 | 1)
            pos = _write_double(out, pos, m_dbl[j, k])
    for r in range(ml_first[j], ml_first[j] + ml_count[j]):
        ls = _log_size(ml_dtype[r], ml_dvalue[r], ml_btype[r], ml_bvalue[r])
        out[pos] = 0x8A  # field 17, wire type 2: varint 0x8A 0x01
        out[pos + 1] = 0x01
        pos = _write_varint(out, pos + 2, ls)
        pos = _write_log(out, pos, ml_dtype[r], ml_dvalue[r], ml_btype[r], ml_bvalue[r])
    return pos


@_jit
def _point_size(i, p_str, p_int, p_flag, p_dbl, p_cov, pl_first, pl_count, pl_dtype, pl_dvalue, pl_btype,
                pl_bvalue):
    s = _str_size(1, p_str[i, 0, 1]) + 1 + varint_size(p_int[i, 0])
    s += _str_size(3, p_str[i, 1, 1]) + _str_size(4, p_str[i, 2, 1])
    for k in range(3):
        if p_flag[i, k] != 0:
            s += 2
    if p_int[i, 1] >= 0:
        s += 1 + varint_size(p_int[i, 1])
    if p_int[i, 2] >= 0:
        s += 1 + varint_size(p_int[i, 2])
    s += _str_size(10, p_str[i, 3, 1])
    if p_int[i, 3] >= 0:
        s += 1 + varint_size(p_int[i, 3])
    s += _str_size(12, p_str[i, 4, 1])
    for k in range(3, 6):
        if p_flag[i, k] != 0:
            s += 2
    for c in range(2):
        for k in range(3):
            if _is_set(p_dbl[i, 3 * c + k]):
                s += 2 + 8 if 3 * c + k >= 0 else 0
        if _is_set(p_cov[i, c, 0]):
            s += 2 + 1 + 48
    for r in range(pl_first[i], pl_first[i] + pl_count[i]):
        ls = _log_size(pl_dtype[r], pl_dvalue[r], pl_btype[r], pl_bvalue[r])
        s += 2 + varint_size(ls) + ls
    return s


@_jit
def _write_point_head(out, pos, i, strings, p_str, p_int, p_flag, p_dbl, p_cov, pl_first, pl_count, pl_dtype,
                      pl_dvalue, pl_btype, pl_bvalue):
    pos = _write_str(out, pos, 1, strings, p_str[i, 0, 0], p_str[i, 0, 1])
    out[pos] = 0x10
    pos = _write_varint(out, pos + 1, p_int[i, 0])
    pos = _write_str(out, pos, 3, strings, p_str[i, 1, 0], p_str[i, 1, 1])
    pos = _write_str(out, pos, 4, strings, p_str[i, 2, 0], p_str[i, 2, 1])
    for k in range(3):
        if p_flag[i, k] != 0:
            out[pos] = np.uint8((5 + k) << 3)
            out[pos + 1] = 1
            pos += 2
    if p_int[i, 1] >= 0:
        out[pos] = 0x40
        pos = _write_varint(out, pos + 1, p_int[i, 1])
    if p_int[i, 2] >= 0:
        out[pos] = 0x48
        pos = _write_varint(out, pos + 1, p_int[i, 2])
    pos = _write_str(out, pos, 10, strings, p_str[i, 3, 0], p_str[i, 3, 1])
    if p_int[i, 3] >= 0:
        out[pos] = 0x58
        pos = _write_varint(out, pos + 1, p_int[i, 3])
    pos = _write_str(out, pos, 12, strings, p_str[i, 4, 0], p_str[i, 4, 1])
    for k in range(3, 6):
        if p_flag[i, k] != 0:
            out[pos] = np.uint8((10 + k) << 3)
            out[pos + 1] = 1
            pos += 2
    for c in range(2):
        for k in range(3):
            if _is_set(p_dbl[i, 3 * c + k]):
                pos = _write_varint(out, pos, (16 + 4 * c + k) << 3 | 1)
                pos = _write_double(out, pos, p_dbl[i, 3 * c + k])
        if _is_set(p_cov[i, c, 0]):
            pos = _write_varint(out, pos, (19 + 4 * c) << 3 | 2)
            out[pos] = 48
            pos += 1
            for k in range(6):
                pos = _write_double(out, pos, p_cov[i, c, k])
    for r in range(pl_first[i], pl_first[i] + pl_count[i]):
        ls = _log_size(pl_dtype[r], pl_dvalue[r], pl_btype[r], pl_bvalue[r])
        out[pos] = 0xC2  # field 24, wire type 2
        out[pos + 1] = 0x01
        pos = _write_varint(out, pos + 2, ls)
        pos = _write_log(out, pos, pl_dtype[r], pl_dvalue[r], pl_btype[r], pl_bvalue[r])
    return pos


@_jit
def encode_points(strings, p_str, p_int, p_flag, p_dbl, p_cov, m_first, m_count, m_str, m_type, m_flag, m_dbl,
                  pl_first, pl_count, pl_dtype, pl_dvalue, pl_btype, pl_bvalue,
                  ml_first, ml_count, ml_dtype, ml_dvalue, ml_btype, ml_bvalue, prefix):
    """Point messages, one after the other; ``prefix`` 4: each preceded by its size (uint32 LE, version 5).

    Measures of point ``i`` are rows ``m_first[i] .. m_first[i] + m_count[i] - 1``.
    Returns ``(bytes, sizes)``: the sizes of the messages (without prefixes).
    """
    n = p_str.shape[0]
    n_meas = m_str.shape[0]
    msize = np.zeros(n_meas, np.int64)
    for j in range(n_meas):
        msize[j] = _measure_size(j, m_str, m_type, m_flag, m_dbl, ml_first, ml_count, ml_dtype, ml_dvalue,
                                 ml_btype, ml_bvalue)
    psize = np.zeros(n, np.int64)
    total = 0
    for i in range(n):
        s = _point_size(i, p_str, p_int, p_flag, p_dbl, p_cov, pl_first, pl_count, pl_dtype, pl_dvalue, pl_btype,
                        pl_bvalue)
        for j in range(m_first[i], m_first[i] + m_count[i]):
            s += 2 + varint_size(msize[j]) + msize[j]
        psize[i] = s
        total += s + prefix
    out = np.empty(total, np.uint8)
    pos = 0
    for i in range(n):
        if prefix == 4:
            v = psize[i]
            for k in range(4):
                out[pos + k] = np.uint8((v >> (8 * k)) & 0xFF)
            pos += 4
        pos = _write_point_head(out, pos, i, strings, p_str, p_int, p_flag, p_dbl, p_cov, pl_first, pl_count,
                                pl_dtype, pl_dvalue, pl_btype, pl_bvalue)
        for j in range(m_first[i], m_first[i] + m_count[i]):
            out[pos] = 0xCA  # field 25, wire type 2
            out[pos + 1] = 0x01
            pos = _write_varint(out, pos + 2, msize[j])
            pos = _write_measure(out, pos, j, strings, m_str, m_type, m_flag, m_dbl, ml_first, ml_count, ml_dtype,
                                 ml_dvalue, ml_btype, ml_bvalue)
    return out, psize
