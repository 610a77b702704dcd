"""numba kernels of the engine; their on-disk cache is keyed on the source of this whole package
(:mod:`._cache`), so editing one kernel file never leaves a stale compiled copy of it inside
another file's cached kernels."""

import os as _os

from ._cache import register_kernel_package as _register

_register(_os.path.dirname(_os.path.abspath(__file__)))
