"""numba on-disk cache keyed on the source of a whole kernel package (issue 15).

numba's ``cache=True`` keys a function's cache entry on its *own* file only (a content hash from
numba 0.60 on, modification time and size before).  A cached kernel that calls, or inlines, a
kernel of *another* file keeps running the old callee after that file is edited: a stale
machine-code copy of it, and, when a parallel callee's signature or layout changed, a
segmentation fault (seen with this engine; ``kernels.advance`` calls ``hgrid.hgrid_pairs``).

:func:`register_kernel_package` makes every cached function of the ``.py`` files of one
directory use a source stamp that is the SHA-256 of *all* those files (names and contents).
Editing any kernel file of the package then invalidates the cache entries of every kernel of
the package: numba sees a different stamp in the index and recompiles (overwriting the entry).
The cache files stay where numba puts them (``__pycache__`` next to the source, or
``NUMBA_CACHE_DIR``, or the user-wide cache directory); only the stamp changes.

The locators are inserted at the front of numba's locator list (``CacheImpl._locator_classes``,
an internal of numba, present from 0.59 to at least 0.68); they decline functions outside the
registered directories, which keep numba's own locators.
"""

from __future__ import annotations

import functools
import hashlib
import os
from pathlib import Path

import numba
from numba.core import caching

_REGISTERED: set[str] = set()


@functools.lru_cache(maxsize=None)
def _stamp(directory: str, listing: tuple) -> str:
    # listing = ((name, mtime_ns, size), ...): re-hashed whenever a file changes
    h = hashlib.sha256()
    for name, _, _ in listing:
        h.update(name.encode())
        h.update(b"\0")
        h.update((Path(directory) / name).read_bytes())
        h.update(b"\0")
    return h.hexdigest()


def package_source_stamp(directory) -> str:
    """SHA-256 over the names and contents of the ``*.py`` files of ``directory``."""
    directory = os.path.abspath(directory)
    listing = []
    for path in sorted(Path(directory).glob("*.py")):
        st = path.stat()
        listing.append((path.name, st.st_mtime_ns, st.st_size))
    return _stamp(directory, tuple(listing))


class _PackageStampMixin:
    """Source stamp of the whole registered directory instead of the function's own file."""

    def get_source_stamp(self):
        return ("granflow-kernel-package-v1", package_source_stamp(os.path.dirname(self._py_file)))

    @classmethod
    def from_function(cls, py_func, py_file):
        if os.path.dirname(os.path.abspath(py_file)) not in _REGISTERED:
            return None
        return super().from_function(py_func, py_file)


class PackageUserProvidedCacheLocator(_PackageStampMixin, caching.UserProvidedCacheLocator):
    """``NUMBA_CACHE_DIR`` set: numba's directory, package stamp."""


class PackageInTreeCacheLocator(_PackageStampMixin, caching.InTreeCacheLocator):
    """``__pycache__`` next to the source (the usual case), package stamp."""


class PackageUserWideCacheLocator(_PackageStampMixin, caching.UserWideCacheLocator):
    """Read-only installation: numba's user-wide cache directory, package stamp."""


_LOCATORS = (PackageUserProvidedCacheLocator, PackageInTreeCacheLocator,
             PackageUserWideCacheLocator)


def _impl_class():
    impl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl", None)
    if impl is None or not isinstance(getattr(impl, "_locator_classes", None), list):
        raise ImportError(
            f"numba {numba.__version__} has no CacheImpl._locator_classes list, so granflow "
            "cannot key its kernel cache on the kernel sources (granflow/engine/lib/_cache.py); "
            "use numba 0.59-0.68")
    return impl


def register_kernel_package(directory) -> None:
    """Key the numba cache of every function defined in ``directory``'s ``*.py`` files on the
    whole directory's source.  Must run before those functions are decorated."""
    _REGISTERED.add(os.path.abspath(directory))
    classes = _impl_class()._locator_classes
    for cls in reversed(_LOCATORS):
        if cls not in classes:
            classes.insert(0, cls)
