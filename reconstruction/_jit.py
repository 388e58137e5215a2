"""Compiled kernels for the hot loops of the reconstruction (decision 0062).

`njit` is numba's nopython compiler with the on-disk cache (the first call in a fresh checkout compiles and
stores the machine code beside the module in __pycache__, later processes load it), without the GIL, and with
NumPy's error model: a division by zero gives ±inf or NaN as in the NumPy code the kernels replace, instead of
numba's default ZeroDivisionError, which stopped a frame when a point fell in the projector's plane (z = 0;
found by the placement sweep).
Kernels are plain loops over flat arrays; everything around them stays NumPy. One thread: the figures
in the README are per core.
"""

from __future__ import annotations

import numba


def njit(*args, **kwargs):
    """numba.njit(cache=True, nogil=True, error_model="numpy"), usable as @njit or @njit(...)."""
    kwargs.setdefault("cache", True)
    kwargs.setdefault("error_model", "numpy")
    kwargs.setdefault("nogil", True)
    return numba.njit(*args, **kwargs)
