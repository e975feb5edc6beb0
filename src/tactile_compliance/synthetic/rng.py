"""Keyed, independent random streams for the synthetic generator.

See docs/synthetic.md, "Determinism".
"""

from __future__ import annotations

import hashlib

import numpy as np

__all__ = ["log_uniform", "stream"]


def stream(seed: int, *keys: object) -> np.random.Generator:
    """A PCG64 generator for ``seed`` and the given keys (ints, strings, floats).

    The same (seed, keys) give the same numbers on every machine and in every process,
    whatever else was drawn before (no dependence on order, worker count or Python's
    salted ``hash``). See docs/synthetic.md, "Determinism".
    """
    if seed < 0:
        raise ValueError(f"seed must be >= 0, got {seed}")
    # The keys' stable digest (ints, strings, floats), as four 32-bit words.
    text = "\x1f".join(f"{type(k).__name__}:{k}" for k in keys).encode("utf-8")
    digest = hashlib.blake2b(text, digest_size=16).digest()
    words = [seed & 0xFFFFFFFF, (seed >> 32) & 0xFFFFFFFF]
    words += [int.from_bytes(digest[i : i + 4], "little") for i in range(0, 16, 4)]
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence(words)))


def log_uniform(rng: np.random.Generator, low: float, high: float) -> float:
    """A draw from ``rng``, uniform in log10 between ``low`` and ``high`` (same unit)."""
    return float(10.0 ** rng.uniform(np.log10(low), np.log10(high)))
