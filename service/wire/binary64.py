"""Columns of float64s sent as base64 text (RFC 4648's alphabet, padded): read by one compiled
pass into the bytes' numbers.

A batch of 500 trajectories of 30 points is three columns of 160 kB of base64, which the standard
library checks with a regular expression and then decodes, two passes in all.
:func:`read_binary64` takes exactly the texts of RFC 4648 section 4 with their padding: a length
that is a multiple of four, the alphabet ``A-Z a-z 0-9 + /`` only, and ``=`` only as the last one
or two characters (no line breaks, spaces or other characters). :func:`first_beyond` finds the
first number out of a range in one pass without temporary arrays. The kernels are compiled (or
loaded from numba's cache) when this module is imported, so that no request waits for them.
"""

from __future__ import annotations

import numba
import numpy as np

ALPHABET = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/"
#: Each byte's value in the alphabet, 255 for a byte outside it (``=`` too).
VALUES = np.full(256, 255, dtype=np.uint8)
VALUES[np.frombuffer(ALPHABET, dtype=np.uint8)] = np.arange(64, dtype=np.uint8)
PAD = ord("=")


def read_binary64(text: str) -> np.ndarray | None:
    """The little-endian float64s whose bytes ``text`` encodes (a new, writable native array),
    or None if ``text`` is not padded base64 of a whole number of 8-byte numbers."""
    try:
        raw = np.frombuffer(text.encode("ascii"), dtype=np.uint8)
    except UnicodeEncodeError:
        return None
    if len(raw) % 4:
        return None
    out = np.empty(len(raw) // 4 * 3, dtype=np.uint8)
    size = _decode(raw, VALUES, out)
    if size < 0 or size % 8:
        return None
    numbers = out[:size].view("<f8")
    return numbers if numbers.dtype.isnative else numbers.astype(np.float64)


def first_beyond(numbers: np.ndarray, limit: float) -> int:
    """The index of the first of ``numbers`` that is not finite or is beyond +-``limit``; -1 if
    none is."""
    return int(_first_beyond(numbers, float(limit)))


@numba.njit(cache=True)
def _first_beyond(numbers, limit):
    for i in range(len(numbers)):
        if not abs(numbers[i]) <= limit:
            return i
    return -1


@numba.njit(cache=True)
def _decode(text, values, out):
    """Decode ``text`` (bytes, a multiple of four) into ``out``: the number of bytes written,
    or -1 for a byte outside the alphabet or padding anywhere but the last two places."""
    n = len(text)
    if n == 0:
        return 0
    pad = 0
    if text[n - 1] == PAD:
        pad = 2 if text[n - 2] == PAD else 1
    quads = n // 4 - (1 if pad else 0)
    bad = 0
    for q in range(quads):
        a = np.int64(values[text[4 * q]])
        b = np.int64(values[text[4 * q + 1]])
        c = np.int64(values[text[4 * q + 2]])
        d = np.int64(values[text[4 * q + 3]])
        bad |= a | b | c | d
        bits = (a << 18) | (b << 12) | (c << 6) | d
        out[3 * q] = (bits >> 16) & 255
        out[3 * q + 1] = (bits >> 8) & 255
        out[3 * q + 2] = bits & 255
    size = 3 * quads
    if pad:
        i = n - 4
        a = np.int64(values[text[i]])
        b = np.int64(values[text[i + 1]])
        c = np.int64(0) if pad == 2 else np.int64(values[text[i + 2]])
        bad |= a | b | c
        bits = (a << 18) | (b << 12) | (c << 6)
        out[size] = (bits >> 16) & 255
        size += 1
        if pad == 1:
            out[size] = (bits >> 8) & 255
            size += 1
    return -1 if bad & 192 else size


_decode(np.frombuffer(b"AAAAAAAAAAA=", dtype=np.uint8), VALUES, np.empty(9, dtype=np.uint8))
first_beyond(np.zeros(1), 1.0)
