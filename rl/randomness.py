"""Random draws that belong to an episode, not to the order in which episodes are played.

An evaluation plays a fixed list of episodes in batches; which row plays which episode, and what
was evaluated before, depend on the batch size and on the caller. A generator that lives in the
policy would hand each episode the draws left over by the others, so the same episode could play
differently (issue 33). Here every draw is a pure function of

- the stream: a key made of the method's name and seed (``stream_key``);
- the episode, by what the UAV knows of it: the public map of the canvas it flies over (``canvas_key``: the city's
  grid and buildings under a symmetry, never a user's map or the bundle's version) and its start cell
  (``BatchedEnv.episode_keys``; a tracking episode by its number in the evaluation's list, a fleet episode by its
  UAVs' starts);
- the step of the episode, and the draw's number within that step,

hashed with SplitMix64's finaliser into a uniform in [0, 1). The same episode therefore plays the
same moves whatever else is evaluated, in whatever order, at whatever batch size.
"""

from __future__ import annotations

import hashlib

import numpy as np

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)


def mix(x: np.ndarray) -> np.ndarray:
    """SplitMix64's finaliser on uint64 values (a bijection that scatters every input bit over the output)."""
    x = np.asarray(x, np.uint64).copy()
    x ^= x >> np.uint64(30)
    x *= _M1
    x ^= x >> np.uint64(27)
    x *= _M2
    x ^= x >> np.uint64(31)
    return x


def stream_key(*parts: object) -> np.uint64:
    """A 64-bit key from any printable parts (a method's name and seed, a bundle version): blake2b of their repr."""
    digest = hashlib.blake2b(repr(parts).encode(), digest_size=8).digest()
    return np.uint64(int.from_bytes(digest, "little"))


def canvas_key(digest: str, symmetry: int = 0) -> np.uint64:
    """The key of a canvas: the digest of a city's public map (``Bundle.public_digest``: its grid and buildings,
    no user) under a symmetry of the square. Every key a
    policy's draws are made from starts here, so none names a user."""
    return stream_key("public map", digest, symmetry)


def combine(a: np.ndarray | np.uint64, b: np.ndarray | np.uint64 | int) -> np.ndarray:
    """One key from two (order matters): ``mix(a ^ mix(b + golden))``."""
    with np.errstate(over="ignore"):
        return mix(np.asarray(a, np.uint64) ^ mix(np.asarray(b, np.uint64) + _GOLDEN))


def uniforms(stream: np.uint64, episode: np.ndarray, step: np.ndarray, count: int) -> np.ndarray:
    """[N, count] uniforms in [0, 1) for rows whose episodes have keys ``episode`` [N] and are at ``step`` [N]."""
    with np.errstate(over="ignore"):
        base = combine(combine(np.asarray(episode, np.uint64), stream), np.asarray(step, np.int64).astype(np.uint64))
        bits = mix(base[:, None] + np.arange(1, count + 1, dtype=np.uint64)[None, :] * _GOLDEN)
    return (bits >> np.uint64(11)).astype(np.float64) * (1.0 / (1 << 53))
