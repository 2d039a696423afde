"""numba compilation on first use: geometry imports without numba, and a compiled caller sees the
compiled callee."""
from __future__ import annotations

import subprocess
import sys

import numpy as np

from touch4d.jit import LazyNjit, lazy_njit


@lazy_njit(cache=False)
def _twice(x):
    return 2.0 * x


@lazy_njit(cache=False)
def _twice_plus_one(x):
    return _twice(x) + 1.0


def test_compiled_on_first_call_with_what_it_calls():
    assert isinstance(_twice_plus_one, LazyNjit) and _twice_plus_one._compiled is None
    assert _twice_plus_one(3.0) == 7.0
    assert type(_twice_plus_one.compiled).__name__ == "CPUDispatcher" and _twice._compiled is not None
    assert _twice_plus_one.compiled.nopython_signatures      # compiled in nopython mode


def test_geometry_imports_without_numba_and_renormalize_still_works():
    code = ("import sys, numpy as np\n"
            "from touch4d.geometry import rotation, segment, visibility\n"
            "print('numba' in sys.modules)\n"
            "r = rotation.renormalize(rotation.plane_rotation('xw', 0.3) * (1 + 1e-9))\n"
            "print('numba' in sys.modules, bool(np.allclose(r @ r.T, np.eye(4), atol=1e-12)))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    assert out.stdout.split() == ["False", "True", "True"]
    far = np.diag([1.0, 1.0, 1.0, -1.0]) @ np.diag([1.2, 0.9, 1.0, 1.1])    # a reflection, far from orthogonal
    from touch4d.geometry.rotation import renormalize

    r = renormalize(far)
    assert np.allclose(r @ r.T, np.eye(4), atol=1e-12) and np.isclose(np.linalg.det(r), 1.0)
