"""Random streams: one independent stream per (trace index, model component).

Trace ``i`` of a dataset draws from ``SeedSequence(root, spawn_key=(i, COMPONENT_ID[name]))``, so it is
identical whatever the batch size, worker count or generation order (docs/data-and-metrics.md, section 2).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numpy.random.bit_generator import ISpawnableSeedSequence

COMPONENT_ID = {"path": 0, "motion": 1, "imu": 2, "uwb": 3, "availability": 4, "attitude": 5, "imu_body": 6}

# numpy.random.SeedSequence's hash (numpy/random/bit_generator.pyx), on Python ints modulo 2^32
_INIT_A, _MULT_A, _INIT_B, _MULT_B = 0x43B0D7E5, 0x931E8875, 0x8B51F9DD, 0x58F38DED
_MIX_MULT_L, _MIX_MULT_R, _XSHIFT, _MASK32, _POOL = 0xCA01F9DD, 0x4973F715, 16, 0xFFFFFFFF, 4


def new_root_seed() -> int:
    """Fresh OS entropy as an int, to be stored in the dataset metadata when the user gave no seed."""
    return int(np.random.SeedSequence().entropy)


def _words(n: int) -> list[int]:
    """The uint32 words of a non-negative int, lowest first (``[0]`` for 0), as SeedSequence splits it."""
    out = [n & _MASK32]
    n >>= 32
    while n:
        out.append(n & _MASK32)
        n >>= 32
    return out


def _hashmix(value: int, hc: int) -> tuple[int, int]:
    value ^= hc
    hc = (hc * _MULT_A) & _MASK32
    value = (value * hc) & _MASK32
    return value ^ (value >> _XSHIFT), hc


def _mix(x: int, y: int) -> int:
    r = (_MIX_MULT_L * x - _MIX_MULT_R * y) & _MASK32
    return r ^ (r >> _XSHIFT)


def _mix_in(pool: list[int], hc: int, words: list[int]) -> int:
    """SeedSequence.mix_entropy's last loop: each further word mixed into every pool word (in place)."""
    for w in words:
        for i in range(_POOL):
            h, hc = _hashmix(w, hc)
            pool[i] = _mix(pool[i], h)
    return hc


@lru_cache(maxsize=16)
def _root_pool(root_seed: int) -> tuple[tuple[int, ...], int]:
    """The entropy pool and hash constant of ``SeedSequence(root, spawn_key=...)`` once every word of the
    root is mixed in (the spawn key's words come after them, so this part is the same for every trace)."""
    entropy = _words(root_seed)
    entropy += [0] * (_POOL - len(entropy))  # with a spawn key, the root is padded to the pool size
    pool, hc = [], _INIT_A
    for i in range(_POOL):
        h, hc = _hashmix(entropy[i], hc)
        pool.append(h)
    for src in range(_POOL):
        for dst in range(_POOL):
            if src != dst:
                h, hc = _hashmix(pool[src], hc)
                pool[dst] = _mix(pool[dst], h)
    hc = _mix_in(pool, hc, entropy[_POOL:])
    return tuple(pool), hc


class _SpawnedSeed(ISpawnableSeedSequence):
    """``SeedSequence(root_seed, spawn_key=key)`` for a bit generator: the same words from
    :meth:`generate_state` (the root's part of the hash cached, :func:`_root_pool`), and the real
    SeedSequence for anything else (other word counts, :meth:`spawn`)."""

    def __init__(self, root_seed: int, key: tuple[int, ...]) -> None:
        self.root_seed, self.key = root_seed, key

    def seed_sequence(self) -> np.random.SeedSequence:
        return np.random.SeedSequence(self.root_seed, spawn_key=self.key)

    def generate_state(self, n_words, dtype=np.uint32):
        if n_words != 4 or np.dtype(dtype) != np.uint64:
            return self.seed_sequence().generate_state(n_words, dtype)
        root_pool, hc = _root_pool(self.root_seed)
        pool = list(root_pool)
        _mix_in(pool, hc, [w for k in self.key for w in _words(k)])
        out, hc = [], _INIT_B
        for i in range(8):  # SeedSequence.generate_state: 8 uint32 words, cycling over the pool
            v = pool[i % _POOL] ^ hc
            hc = (hc * _MULT_B) & _MASK32
            v = (v * hc) & _MASK32
            out.append(v ^ (v >> _XSHIFT))
        return np.array([out[j] | (out[j + 1] << 32) for j in range(0, 8, 2)], dtype=np.uint64)

    def spawn(self, n_children):
        return self.seed_sequence().spawn(n_children)


def component_rng(root_seed: int, trace_index: int, component: str) -> np.random.Generator:
    """The generator of one model component of one trace: ``numpy.random.default_rng(SeedSequence(root_seed,
    spawn_key=(trace_index, component id)))``, in the same state, with the root's share of the seed hash
    computed once per root (:class:`_SpawnedSeed`; numpy's own SeedSequence for a negative seed or index)."""
    key = (int(trace_index), COMPONENT_ID[component])
    root = int(root_seed)
    if root < 0 or key[0] < 0:  # SeedSequence refuses these: let it say so
        return np.random.default_rng(np.random.SeedSequence(root, spawn_key=key))
    return np.random.Generator(np.random.PCG64(_SpawnedSeed(root, key)))
