"""The float32 rounding error of Winograd F(4x4, 3x3) and F(6x6, 3x3) for several sets of interpolation points, against
a direct 3x3 correlation, on random tiles and 3x3 kernels (docs/speed.md, float32 accuracy in training).

    python scripts/winograd_points.py [--tiles 20000] [--channels 1]

Builds each point set's matrices by the Toom-Cook construction (exact rationals, sympy), checks the identity
Aᵀ[(G g Gᵀ) ⊙ (Bᵀ d B)]A = d ⋆ g symbolically in 1-D, then evaluates both in float32 and prints the mean
|error| against float64. With `--channels C` every output sums C input channels, the Winograd products in the
transform domain (as the convolution's GEMM sums them). mipnet uses F(4x4, 3x3) with the points 0, ±1, ±2 (and ∞),
Lavin & Gray's.
"""

from __future__ import annotations

import argparse

import numpy as np
import sympy as sp

HALF, THIRD = sp.Rational(1, 2), sp.Rational(1, 3)
#: (output tile side m, finite points; ∞ is always the last point): m + 1 finite points for F(m, 3).
POINT_SETS = [(4, (0, 1, -1, 2, -2)), (4, (0, 1, -1, HALF, -HALF)), (4, (0, 1, -1, HALF, -2)),
              (4, (0, 1, -1, sp.Rational(3, 2), -sp.Rational(3, 2))), (4, (0, 1, -1, 2 * THIRD, -2 * THIRD)),
              (6, (0, 1, -1, 2, -2, HALF, -HALF)), (6, (0, 1, -1, 2, -2, HALF, -3)),
              (6, (0, 1, -1, sp.Rational(3, 2), -sp.Rational(3, 2), 2 * THIRD, -2 * THIRD))]


def matrices(points, m: int) -> tuple[sp.Matrix, sp.Matrix, sp.Matrix]:
    """(Aᵀ m x n, G n x 3, Bᵀ n x n), n = m + 2, of F(m, 3) with the finite ``points`` and ∞ (Toom-Cook)."""
    r = 3
    n = m + r - 1
    a = [sp.Rational(p) for p in points]
    x = sp.symbols("x")
    at, g, bt = sp.zeros(m, n), sp.zeros(n, r), sp.zeros(n, n)
    for j, aj in enumerate(a):
        # f_j = Π_{l≠j} (a_j - a_l): the Lagrange denominator of point j
        f = sp.prod([aj - al for l, al in enumerate(a) if l != j])
        for i in range(m):
            at[i, j] = aj ** i
        for k in range(r):
            g[j, k] = aj ** k / f
        for k, c in enumerate(sp.Poly(sp.prod([x - al for l, al in enumerate(a) if l != j]), x).all_coeffs()[::-1]):
            bt[j, k] = c
    at[m - 1, n - 1], g[n - 1, r - 1] = 1, 1
    for k, c in enumerate(sp.Poly(sp.prod([x - al for al in a]), x).all_coeffs()[::-1]):
        bt[n - 1, k] = c
    return at, g, bt


def exact_1d(at, g, bt) -> bool:
    """Whether Aᵀ[(G g) ⊙ (Bᵀ d)] is the correlation of d (n values) with g (3) as polynomials."""
    m, n = at.shape
    d, w = sp.symbols(f"d0:{n}"), sp.symbols("g0:3")
    y = at * sp.Matrix(g * sp.Matrix(w)).multiply_elementwise(bt * sp.Matrix(d))
    return all(sp.expand(y[i] - sum(w[k] * d[i + k] for k in range(3))) == 0 for i in range(m))


def float32_error(at, g, bt, tiles: int, channels: int, seed: int = 0) -> tuple[float, float]:
    """Mean |error| of the m x m outputs of Winograd and of the direct sum, both in float32, against float64."""
    m, n = at.shape
    rng = np.random.default_rng(seed)
    at, g, bt = (np.array(mat.tolist(), dtype=np.float64) for mat in (at, g, bt))
    d, w = rng.standard_normal((tiles, channels, n, n)), rng.standard_normal((tiles, channels, 3, 3))
    # y[t, i, j] = Σ_{c,a,b} d[t, c, i + a, j + b] w[t, c, a, b]
    exact = np.stack([[(d[:, :, i:i + 3, j:j + 3] * w).sum((1, 2, 3)) for j in range(m)] for i in range(m)])
    f = np.float32
    u = np.einsum("ak,tckl,bl->tcab", g.astype(f), w.astype(f), g.astype(f)).astype(f)
    v = np.einsum("ak,tckl,bl->tcab", bt.astype(f), d.astype(f), bt.astype(f)).astype(f)
    y = np.einsum("ia,tab,jb->tij", at.astype(f), (u * v).sum(1, dtype=f), at.astype(f))
    direct = np.stack([[(d[:, :, i:i + 3, j:j + 3].astype(f) * w.astype(f)).sum((1, 2, 3), dtype=f) for j in range(m)]
                       for i in range(m)])
    exact, direct = exact.transpose(2, 0, 1), direct.transpose(2, 0, 1)
    return float(np.abs(y - exact).mean()), float(np.abs(direct - exact).mean())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tiles", type=int, default=20000)
    parser.add_argument("--channels", type=int, default=1, help="input channels summed into each output")
    args = parser.parse_args()
    for m, points in POINT_SETS:
        at, g, bt = matrices(points, m)
        assert exact_1d(at, g, bt), points
        wino, direct = float32_error(at, g, bt, args.tiles, args.channels)
        print(f"F({m}x{m}, 3x3), points {', '.join(map(str, points))}, inf: Winograd {wino:.3e}, direct {direct:.3e}, "
              f"ratio {wino / direct:.2f}")


if __name__ == "__main__":
    main()
