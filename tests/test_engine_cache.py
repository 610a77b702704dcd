"""The numba cache of the engine kernels is keyed on the source of the whole kernel package
(issue 15): editing one kernel file must not leave a stale copy of it compiled into another
file's cached kernels (numba keys each function on its own file only)."""

import subprocess
import sys
import textwrap

from granflow.engine.lib import _cache, kernels
from granflow.engine.lib.hgrid import hgrid_pairs


def _write_package(root, value):
    pkg = root / "kpkg"
    pkg.mkdir(exist_ok=True)
    (pkg / "__init__.py").write_text(textwrap.dedent("""\
        import os
        from granflow.engine.lib._cache import register_kernel_package
        if os.environ.get("REGISTER") == "1":
            register_kernel_package(os.path.dirname(os.path.abspath(__file__)))
        """))
    (pkg / "callee.py").write_text(textwrap.dedent(f"""\
        from numba import njit
        @njit(cache=True)
        def g():
            return {value}
        """))
    (pkg / "caller.py").write_text(textwrap.dedent("""\
        from numba import njit
        from .callee import g
        @njit(cache=True)
        def f():
            return g()
        """))


def _run(root, register):
    code = ("from kpkg.caller import f; v = f(); "
            "print(v, sum(f.stats.cache_hits.values()))")
    res = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True,
                         env={"REGISTER": "1" if register else "0", "PATH": "/usr/bin:/bin"},
                         timeout=300)
    assert res.returncode == 0, res.stderr
    value, hits = res.stdout.split()
    return int(value), int(hits)


def test_editing_a_callee_file_recompiles_its_cached_callers(tmp_path):
    # numba's own keying: the caller keeps the stale callee (this is what the locator fixes)
    plain = tmp_path / "plain"
    plain.mkdir()
    _write_package(plain, 1)
    assert _run(plain, register=False) == (1, 0)
    _write_package(plain, 2)
    assert _run(plain, register=False)[0] == 1  # stale: the edit of callee.py is not seen
    # keyed on the package source: the edit is seen, and an unchanged package hits the cache
    keyed = tmp_path / "keyed"
    keyed.mkdir()
    _write_package(keyed, 1)
    assert _run(keyed, register=True) == (1, 0)
    assert _run(keyed, register=True) == (1, 1)
    _write_package(keyed, 2)
    assert _run(keyed, register=True) == (2, 0)
    assert _run(keyed, register=True) == (2, 1)


def test_engine_kernels_are_keyed_on_the_whole_package(tmp_path):
    lib = kernels.__file__.rsplit("/", 1)[0]
    stamp = _cache.package_source_stamp(lib)
    for dispatcher in (kernels.advance, hgrid_pairs):
        locator = dispatcher._cache._impl.locator
        assert isinstance(locator, _cache._PackageStampMixin)
        assert locator.get_source_stamp()[1] == stamp
    # the stamp changes with any file of the directory
    d = tmp_path / "pkg"
    d.mkdir()
    (d / "a.py").write_text("x = 1\n")
    (d / "b.py").write_text("y = 1\n")
    s0 = _cache.package_source_stamp(d)
    (d / "b.py").write_text("y = 2\n")
    assert _cache.package_source_stamp(d) != s0
