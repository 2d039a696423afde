"""Quaternion to rotation matrix: the candidates, timed on the loads the library has.

The library keeps one conversion (touch4d.geometry.quaternion.to_matrix); this chose it. Loads: one
quaternion (a pose: the rigid hand, the tracker's calibration, a view's hand) and a stack of 16 and
25 (the articulated hand's bones and WebXR's joints), as the tactile loop meets them at 1 kHz.
Candidates, each for a stack (K, 4) and a single (4,):
  closed form     the nine entries written out, on the components (columns of the stack)
  quadratic form  each entry a quadratic form of q: the outer products q q^T (K, 16) times a
                  constant (16, 9) in one matrix product
  scipy           Rotation.from_quat(q).as_matrix()
Each figure: CPU microseconds per conversion (median of 5 rounds), and its ratio to the fastest of the load.
Then one pose's product and canonical form (a served participant's hand, per input): the library's,
on Python floats, against the same formulas on numpy's scalars.

    .venv/bin/python bench/bench_quaternion.py [--number 20000]
"""
from __future__ import annotations

import argparse
import time

import touch4d  # noqa: F401  first: it caps BLAS thread pools before numpy loads
import numpy as np
from scipy.spatial.transform import Rotation

from touch4d.geometry import quaternion


def closed_form(q: np.ndarray) -> np.ndarray:
    """The nine entries written out; components as arrays (a stack) or floats (a single)."""
    x, y, z, w = np.moveaxis(q, -1, 0) if q.ndim > 1 else q.tolist()
    xx, yy, zz, xy, xz, yz, wx, wy, wz = x * x, y * y, z * z, x * y, x * z, y * z, w * x, w * y, w * z
    m = np.array([[1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy)],
                  [2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx)],
                  [2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy)]])
    return np.moveaxis(m, (0, 1), (-2, -1)) if q.ndim > 1 else m


def scipy_rotation(q: np.ndarray) -> np.ndarray:
    return Rotation.from_quat(q).as_matrix()


def multiply_on_numpy_scalars(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz])


def canonical_in_numpy(q: np.ndarray) -> np.ndarray:
    q = q / np.sqrt(q @ q)
    return -q if q[3] < 0 else q


CANDIDATES = {"closed form": closed_form, "quadratic form": quaternion.to_matrix, "scipy": scipy_rotation}


def per_call(fn, q, number: int) -> float:
    """Median over 5 rounds of the mean CPU time per call, microseconds (the machine's other load not counted)."""
    rounds = []
    for _ in range(5):
        start = time.process_time()
        for _ in range(number):
            fn(q)
        rounds.append((time.process_time() - start) / number * 1e6)
    return float(np.median(rounds))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--number", type=int, default=20000, help="conversions per timed round")
    args = parser.parse_args(argv)
    loads = {"1 quaternion": Rotation.random(random_state=1).as_quat(),
             "16 (bones)": Rotation.random(16, random_state=2).as_quat(),
             "25 (joints)": Rotation.random(25, random_state=3).as_quat()}
    print(f"quaternion -> matrix, us per call (median of 5 rounds of {args.number}); ratio to the fastest")
    print(f"{'load':<14}" + "".join(f"{name:>24}" for name in CANDIDATES))
    for load, q in loads.items():
        reference = Rotation.from_quat(q).as_matrix()
        for name, fn in CANDIDATES.items():   # the same matrices, or the figures mean nothing
            assert np.allclose(fn(q), reference, atol=1e-12), name
        us = {name: per_call(fn, q, args.number) for name, fn in CANDIDATES.items()}
        best = min(us.values())
        print(f"{load:<14}" + "".join(f"{t:>14.2f} ({t / best:4.2f}x)" for t in us.values()))
    a, b = Rotation.random(2, random_state=4).as_quat()
    b = -3.0 * b   # not unit, w < 0: canonical has both to do
    for name, library, numpy_scalars, q in (("multiply", lambda q: quaternion.multiply(a, q), lambda q:
                                             multiply_on_numpy_scalars(a, q), b),
                                            ("canonical", quaternion.canonical, canonical_in_numpy, b)):
        assert np.allclose(library(q), numpy_scalars(q), rtol=0, atol=1e-15), name   # equal to rounding
        new, old = per_call(library, q, args.number), per_call(numpy_scalars, q, args.number)
        print(f"{name:<14}{new:>8.2f} us (Python floats) vs {old:.2f} us (numpy scalars): {new / old:.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
