"""Physical-optics (PO) integrals of flat facets, in closed form and stable at every incidence.

A flat facet seen by the monostatic radar at the origin returns, relative to a reference range,

    S = sqrt(4 pi) / lambda * Gamma * cos(theta) * I,     I = integral over the facet of exp(j psi(r)) dA,

with psi(r) = +2 k R(r) the round-trip phase (metres: S is a "square-root RCS", |S|^2 = sigma). For
a flat plate of area A at normal incidence in its far field I = A, so sigma = 4 pi A^2 Gamma^2 /
lambda^2. The world takes psi linear across each (small) facet, through the exact phases at its
corners, which makes I a closed form:

- :func:`phi1`: (exp(jx) - 1) / (j x) = exp(jx/2) sinc(x/2), the integral of exp(j x s) for s in [0, 1];
- :func:`parallelogram_factor`: I / A of a parallelogram = exp(j psi_c) sinc(a/2) sinc(b/2),
  a and b the phase differences along its two sides;
- :func:`quadratic_integral` / :func:`quadratic_factor`: the same across a strip whose phase is
  quadratic (a cylinder's curvature), over any part of it, exactly, through Fresnel integrals;
- :func:`triangle_factor`: I / A of a triangle from its three corner phases (Hermite-Genocchi: the
  second divided difference of exp(jx)), evaluated around the middle phase so that only an
  all-corners-in-phase facet needs the series branch;
- :func:`polygon_integral`: Gordon's edge sum for any flat polygon and any vector q,
  I = sum_edges (q_t . m_i) |e_i| exp(j q . c_i) sinc(q . e_i / 2) / (j |q_t|^2), m_i the edge's outward
  in-plane normal, c_i its midpoint, q_t the part of q in the facet plane; q_t -> 0 (q along the
  normal, all of the facet in phase) takes the limit A exp(j q . r0). Used by the tests as the
  independent closed form.

All functions are vectorised over leading axes and exact to rounding (no quadrature).
"""

from __future__ import annotations

import numpy as np

SERIES_BELOW_RAD = 1e-2  # triangle phase spread under which the second-order series is used (error < 1e-9)


def sinc(x: np.ndarray) -> np.ndarray:
    """sin(x) / x (1 at 0), radians."""
    return np.sinc(np.asarray(x) / np.pi)


def phi1(x: np.ndarray) -> np.ndarray:
    """(exp(jx) - 1) / (j x) = integral_0^1 exp(j x s) ds, stable at x = 0."""
    x = np.asarray(x, dtype=np.float64)
    return np.exp(0.5j * x) * sinc(0.5 * x)


def parallelogram_factor(psi_c: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(1/A) integral of exp(j psi) over a parallelogram with a linear phase: psi_c at its centre,
    a and b the phase differences between the ends of its two sides (radians)."""
    return np.exp(1j * np.asarray(psi_c)) * sinc(0.5 * np.asarray(a)) * sinc(0.5 * np.asarray(b))


QUADRATIC_FLOOR_RAD = 1e-6  # |q| below this is taken as this (the change is below rounding)


def quadratic_integral(s: np.ndarray, q: np.ndarray, lo: np.ndarray | float = -0.5,
                       hi: np.ndarray | float = 0.5) -> np.ndarray:
    """integral_lo^hi exp(j (s x + q x^2)) dx (0 where hi <= lo): a strip whose phase is quadratic
    across it, x its position in units of its width (-1/2 .. 1/2 for the whole strip).

    Completing the square: sqrt(pi / (2 |q|)) exp(-j s^2 / (4 q)) [F(u(hi)) - F(u(lo))] with
    F = C + j sign(q) S the Fresnel integrals at u(x) = sqrt(2 |q| / pi) (x + s / (2 q)). Exact for
    every s and q (the difference of F stays accurate as q -> 0: it scales like sqrt(q))."""
    from scipy.special import fresnel

    s = np.asarray(s, dtype=np.float64)
    q = np.asarray(q, dtype=np.float64)
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    sign = np.where(q < 0, -1.0, 1.0)
    q = sign * np.maximum(np.abs(q), QUADRATIC_FLOOR_RAD)
    scale = np.sqrt(2 * np.abs(q) / np.pi)
    centre = s / (2 * q)
    s1, c1 = fresnel(scale * (hi + centre))
    s0, c0 = fresnel(scale * (lo + centre))
    diff = (c1 - c0) + 1j * sign * (s1 - s0)
    out = np.sqrt(np.pi / (2 * np.abs(q))) * np.exp(-1j * s * s / (4 * q)) * diff
    return np.where(hi > lo, out, 0.0)


def quadratic_factor(s: np.ndarray, q: np.ndarray) -> np.ndarray:
    """integral_{-1/2}^{1/2} exp(j (s x + q x^2)) dx: a whole strip with phase step s between its
    edges and curvature q (the edges lie q / 4 off the centre's phase)."""
    return quadratic_integral(s, q)


def triangle_factor(psi0: np.ndarray, psi1: np.ndarray, psi2: np.ndarray) -> np.ndarray:
    """(1/A) integral of exp(j psi) over a triangle, psi linear with corner values psi0..2 (radians).

    Equals 2 * (second divided difference of -exp(jx) at the three phases). Around the middle phase m
    with a = min - m <= 0 <= b = max - m it is exp(j m) * 2 (phi1(b) - phi1(a)) / (j (b - a)): the
    difference quotient only cancels when all three phases agree (b - a small), where the series
    exp(j mean) (1 - var / 2), var = sum (psi_i - mean)^2 / 12, is used instead.
    """
    p = np.stack(np.broadcast_arrays(*(np.asarray(x, dtype=np.float64) for x in (psi0, psi1, psi2))))
    lo, hi = p.min(0), p.max(0)
    mid = p.sum(0) - lo - hi
    a, b = lo - mid, hi - mid
    spread = b - a
    wide = spread >= SERIES_BELOW_RAD
    safe = np.where(wide, spread, 1.0)
    exact = np.exp(1j * mid) * 2.0 * (phi1(b) - phi1(a)) / (1j * safe)
    mean = p.mean(0)
    var = ((p - mean) ** 2).sum(0) / 12.0
    series = np.exp(1j * mean) * (1.0 - 0.5 * var)
    return np.where(wide, exact, series)


def polygon_integral(vertices: np.ndarray, q: np.ndarray) -> complex:
    """Integral of exp(j q . r) dA over a flat convex or concave polygon (N, 3), any q (3,) (Gordon).

    Vertices in order around the polygon (either sense). Returns m^2 (complex)."""
    v = np.asarray(vertices, dtype=np.float64)
    q = np.asarray(q, dtype=np.float64)
    e = np.roll(v, -1, axis=0) - v
    n = np.cross(v - v.mean(0), np.roll(v, -1, axis=0) - v.mean(0)).sum(0)
    area = 0.5 * np.linalg.norm(n)
    n = n / (2 * area)
    q_t = q - (q @ n) * n
    size = np.linalg.norm(e, axis=1).max()
    if np.linalg.norm(q_t) * size < 1e-6:  # the whole polygon in phase (q along its normal)
        return complex(area * np.exp(1j * (q @ v[0])))
    m = np.cross(e, n)  # outward in-plane normal times |e| for counter-clockwise order about n
    centres = v + 0.5 * e
    terms = (m @ q_t) * np.exp(1j * (centres @ q)) * sinc(0.5 * (e @ q))
    return complex(terms.sum() / (1j * (q_t @ q_t)))


def rcs_of_integral(integral: complex | np.ndarray, wavelength_m: float, reflectivity: float = 1.0,
                    cos_theta: float | np.ndarray = 1.0) -> np.ndarray:
    """Monostatic PO radar cross-section (m^2) of a facet whose phase integral is ``integral``:
    sigma = 4 pi |Gamma cos(theta) I|^2 / lambda^2."""
    return 4 * np.pi * np.abs(reflectivity * np.asarray(cos_theta) * np.asarray(integral)) ** 2 / wavelength_m ** 2
