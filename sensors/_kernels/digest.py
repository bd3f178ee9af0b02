"""A 64-bit digest of an array's bytes, to tell whether a buffer changed in place.

The replay cache of ``sensors.simulate.Run`` keeps the very point chunks its first pass
handed out (no copy) and, before replaying one, checks that its bytes are still the
ones it was given: a consumer may change a chunk it was handed.

The digest is ``sum_i mix(w_i xor (i * PHI))`` modulo 2^64 over the 64-bit words
``w_i`` of the buffer (the last, partial word zero-padded), with ``mix`` the SplitMix64
finaliser (Steele, Lea & Flood 2014, "Fast splittable pseudorandom number generators",
OOPSLA; constants of Vigna's splitmix64.c) and ``PHI`` = 2^64 / golden ratio. ``mix`` is
a bijection, so a change of any one word always changes the digest; changes of several
words collide with probability about 2^-64 (not a cryptographic hash: nothing here is
adversarial). Integer addition is associative, so the parallel sum gives the same
digest for any thread count.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from raytrace.config import CACHE, ERROR_MODEL

PHI = np.uint64(0x9E3779B97F4A7C15)
M1 = np.uint64(0xBF58476D1CE4E5B9)
M2 = np.uint64(0x94D049BB133111EB)


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def mix(z):
    """SplitMix64's finaliser: a bijection of uint64."""
    z = (z ^ (z >> np.uint64(30))) * M1
    z = (z ^ (z >> np.uint64(27))) * M2
    return z ^ (z >> np.uint64(31))


@njit(parallel=True, cache=CACHE, error_model=ERROR_MODEL)
def digest_words(words, tail):
    """Digest of ``words`` (m,) uint64 followed by ``tail`` (0 to 7,) uint8 (the bytes
    after the last whole word, zero-padded to one more word)."""
    m = words.shape[0]
    h = np.uint64(0)
    for i in prange(m):
        h += mix(words[i] ^ (np.uint64(i) * PHI))
    if tail.shape[0] > 0:
        w = np.uint64(0)
        for k in range(tail.shape[0]):
            w |= np.uint64(tail[k]) << np.uint64(8 * k)
        h += mix(w ^ (np.uint64(m) * PHI))
    return h


def digest(a: np.ndarray) -> int:
    """Digest of a C-contiguous array's bytes (any dtype, structured included)."""
    b = a.reshape(-1).view(np.uint8)
    m = len(b) // 8
    return int(digest_words(b[:m * 8].view(np.uint64), b[m * 8:]))
