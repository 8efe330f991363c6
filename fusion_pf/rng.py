"""Random-number-generator handling shared by every random function.

Every function that draws random numbers takes ``rng`` (a
:class:`numpy.random.Generator` or an int seed or None), as scikit-image does, and
never touches the global ``np.random`` state.
"""

from __future__ import annotations

import numpy as np

from .errors import InputError


def as_rng(
    rng: np.random.Generator | int | None, *, bit_generator: type[np.random.BitGenerator] = np.random.PCG64
) -> np.random.Generator:
    """Return a Generator for ``rng``.

    Parameters
    ----------
    rng : numpy.random.Generator, int or None
        A Generator is returned as is (shared state); an int seeds a new
        Generator on ``bit_generator``; None gives a fresh, OS-seeded one.
    bit_generator : numpy BitGenerator class
        For int and None seeds: PCG64 (numpy's default) unless a caller that
        draws heavily asks for another, e.g. SFC64 (about 20 % faster normals).

    Returns
    -------
    numpy.random.Generator
    """
    if isinstance(rng, np.random.Generator):
        return rng
    if rng is None:
        return np.random.Generator(bit_generator())
    if isinstance(rng, (int, np.integer)) and not isinstance(rng, bool):
        if rng < 0:
            raise InputError(f"rng seed must be a non-negative int, got {rng}")
        return np.random.Generator(bit_generator(int(rng)))
    raise InputError(f"rng must be a numpy Generator, a non-negative int seed or None, got {type(rng).__name__}")
