"""Scatterer tracks: the scene's returns as the renderer reads them, at any instant.

Tracks: one per facet, at the mean range of its elements, with the complex sum of its elements
and texture points, each taken relative to that range with the wavenumber
handradar.world.scattering.group_wavenumber (the slope of the phase that the chain's range FFT
sees), so a facet's track reproduces its elements in every range bin to first order in their
spread. Weights (reflectivity, incidence, gain, 1/R^2, shadow) are evaluated at the cast steps,
ranges and phase steps at every physics step; :class:`SurfaceTracks` evaluates the sums at any
instant (the renderer: every chirp). Point scatterers, bounces and static clutter are columns of
:class:`ScatterTracks` whose amplitudes are interpolated linearly.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.interpolate import CubicSpline

from handradar.world.optics import SERIES_BELOW_RAD

# kinds of scatterer columns
DIRECT, BOUNCE, STATIC = 0, 1, 2


def _segments(values: np.ndarray, facet: np.ndarray, n_facets: int) -> np.ndarray:
    """Sum the columns of values (N, E) by facet (E,), facet sorted: (N, n_facets)."""
    out = np.zeros((values.shape[0], n_facets), dtype=values.dtype)
    if facet.size:
        starts = np.flatnonzero(np.r_[True, facet[1:] != facet[:-1]])
        out[:, facet[starts]] = np.add.reduceat(values, starts, axis=1)
    return out


def _lerp_index(times: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    hi = np.clip(np.searchsorted(times, t, side="right"), 1, len(times) - 1)
    lo = hi - 1
    return lo, (t - times[lo]) / (times[hi] - times[lo])


STRIP, TRIANGLE, POINT = "strip", "triangle", "point"


def triangle_centroid_factor(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(1/A) integral of exp(j psi) over a triangle relative to the phase at its centroid, from the
    phase steps a = psi1 - psi0 and b = psi2 - psi0 (radians, float32 arrays): optics.triangle_factor
    around the middle phase, written out to keep the renderer's inner loop short."""
    zero = np.zeros_like(a)
    lo = np.minimum(np.minimum(a, b), zero)
    hi = np.maximum(np.maximum(a, b), zero)
    mid = a + b - lo - hi
    big, small = hi - mid, lo - mid  # >= 0, <= 0
    d = big - small
    wide = d >= SERIES_BELOW_RAD
    m = mid - (a + b) / 3  # the middle corner's phase relative to the centroid
    p1, p2 = m + 0.5 * big, m + 0.5 * small
    s1, s2 = _sinc32(0.5 * big), _sinc32(0.5 * small)
    num = (np.cos(p1) * s1 - np.cos(p2) * s2) + 1j * (np.sin(p1) * s1 - np.sin(p2) * s2)
    exact = num * (2 / np.where(wide, d, 1)).astype(a.dtype) * np.complex64(-1j)
    mean = (a + b) / 3
    var = (mean ** 2 + (a - mean) ** 2 + (b - mean) ** 2) / 12
    return np.where(wide, exact, (1 - 0.5 * var).astype(np.complex64))


def strip_along_factor(s: np.ndarray, q: np.ndarray) -> np.ndarray:
    """integral_{-1/2}^{1/2} exp(j (s x + q x^2)) dx to second order in the curvature q (float32):
    sinc(s / 2) + j q M2(s) - q^2 / 2 M4(s), Mn(s) = integral x^n cos(s x) dx (series below |s| = 3).
    The near field bends the phase along a strip by |q| / 4 <= po_phase_tol_rad; what is left out
    is at most |q|^3 / 2688 (the third-order term at s = 0) plus the series' first dropped term,
    |q| s^6 / 1658880 <= 4.4e-4 |q| just below |s| = 3 (tests/world/test_scene.py). Adding that
    term would change the world's data, so it waits for the next WORLD_VERSION."""
    half = np.float32(0.5) * s
    sn, cs = np.sin(half), np.cos(half)
    big = np.abs(s) > 3
    inv = np.float32(1) / np.where(big, s, np.float32(1))
    inv2 = inv * inv  # powers by products: numpy's ``x ** 3`` and up is a generic pow, 17x slower here
    sn1, cs2 = sn * inv, cs * inv2  # sin(s/2) / s, cos(s/2) / s^2
    s2 = s * s
    s4 = s2 * s2
    m2 = np.where(big, np.float32(0.5) * sn1 + 2 * cs2 - 4 * sn1 * inv2,
                  np.float32(1 / 12) - s2 / np.float32(160) + s4 / np.float32(10752))
    m4 = np.where(big, np.float32(0.125) * sn1 + cs2 - 6 * sn1 * inv2 - 24 * cs2 * inv2 + 48 * sn1 * inv2 * inv2,
                  np.float32(1 / 80) - s2 / np.float32(896) + s4 / np.float32(55296))
    out = np.empty(s.shape, np.complex64)
    out.real = _sinc32(half) - np.float32(0.5) * q * q * m4
    out.imag = q * m2
    return out


def _sinc32(x: np.ndarray) -> np.ndarray:
    """sin(x) / x in float32 (1 at 0)."""
    x = np.where(x == 0, np.float32(1e-20), x)
    return np.sin(x) / x


def _runs(index: np.ndarray) -> list[tuple[int, slice]]:
    """(value, slice) of each run of equal values in a sorted index array."""
    edges = np.flatnonzero(np.diff(index)) + 1
    starts, ends = np.r_[0, edges], np.r_[edges, len(index)]
    return [(int(index[s]), slice(int(s), int(e))) for s, e in zip(starts, ends)]


def _spline_eval(coef: np.ndarray, knots: np.ndarray, t: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Splines with coefficients coef (4, T - 1, E) over the uniform knots' indices, columns ``cols``,
    at sorted instants t -> (N, len(cols)); one Horner pass per knot interval touched."""
    x = np.clip((t - knots[0]) / (knots[1] - knots[0]), 0.0, len(knots) - 1.0)
    i = np.minimum(x.astype(np.int64), len(knots) - 2)
    h = (x - i)[:, None]
    out = np.empty((len(t), len(cols)))
    for seg, rows in _runs(i):
        c = coef[:, seg, cols]
        hh = h[rows]
        out[rows] = ((c[0] * hh + c[1]) * hh + c[2]) * hh + c[3]
    return out


def _lerp_eval(values: np.ndarray, knots: np.ndarray, t: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """values (K, E) at knots, columns ``cols``, interpolated linearly at sorted instants t."""
    lo, frac = _lerp_index(knots, t)
    out = np.empty((len(t), len(cols)), dtype=values.dtype)
    for k, rows in _runs(lo):
        v0, v1 = values[k, cols], values[k + 1, cols]
        out[rows] = v0 + (v1 - v0) * frac[rows, None].astype(values.real.dtype)
    return out


@dataclass
class ElementGroup:
    """Elements of one shape (strips, triangles or texture points), sorted by facet.

    At the physics times (T, E), splined: ``centre_ranges``, the range of each element's phase
    centre, and its phase steps across the element (radians; strip: along the cylinder, between its
    two ends; triangle: corner 1 and corner 2 minus corner 0). At the weight times (Tw, E),
    interpolated linearly: complex ``weights`` (counts; a strip's includes its exact quadratic-phase
    factor across the cylinder, a texture point's its random phase) and ``centres`` (radar frame,
    float32, for diagnostics)."""

    kind: str
    facet: np.ndarray
    centre_ranges: np.ndarray
    weights: np.ndarray
    step_a: np.ndarray | None = None
    step_b: np.ndarray | None = None
    centres: np.ndarray | None = None

    def subset(self, keep: np.ndarray, new_index: np.ndarray) -> ElementGroup:
        m = keep[self.facet]

        def pick(x: np.ndarray | None) -> np.ndarray | None:
            return None if x is None else x[:, m]

        return ElementGroup(self.kind, new_index[self.facet[m]], self.centre_ranges[:, m], self.weights[:, m],
                            pick(self.step_a), pick(self.step_b), pick(self.centres))

    @cached_property
    def splines(self) -> list[np.ndarray]:
        """Cubic-spline coefficients (4, T - 1, E) over the step index (not-a-knot, as CubicSpline) of
        the centre ranges and the phase steps."""
        t = np.arange(self.centre_ranges.shape[0])
        return [CubicSpline(t, x, axis=0).c for x in (self.centre_ranges, self.step_a, self.step_b) if x is not None]


@dataclass
class SurfaceTracks:
    """The facets' coherent sums, evaluated at any instant from their elements and texture points.

    times (T,) physics times (uniform), weight_times (Tw,) a subset of them; per group of elements
    the centre ranges are splined (cubic) and the weights and phase steps (reflectivity, incidence,
    gain, 1/R^2 and shadow: smooth) interpolated linearly to the requested instants; the facet
    centres' ranges facet_ranges (T, F) are the tracks' ranges."""

    times: np.ndarray
    weight_times: np.ndarray
    wavenumber: float  # rad/m, the relative phase exp(+2 j k (R - R_facet))
    groups: list[ElementGroup]
    facet_ranges: np.ndarray

    @property
    def n_facets(self) -> int:
        return self.facet_ranges.shape[1]

    @property
    def n_elements(self) -> int:
        return sum(g.facet.size for g in self.groups if g.kind != POINT)

    @property
    def n_points(self) -> int:
        return sum(g.facet.size for g in self.groups if g.kind == POINT)

    @cached_property
    def _facet_spline(self) -> CubicSpline:
        return CubicSpline(self.times, self.facet_ranges, axis=0)

    def amplitudes(self, times: np.ndarray) -> np.ndarray:
        """Complex amplitude (counts) of every facet track at ``times`` (any shape) -> (*shape, F),
        relative to the facet's own range (the renderer adds its carrier).

        The instants of one call should be close together (a frame): splines and linear
        interpolation are written as small matrix products over the knots they touch."""
        t = np.asarray(times, dtype=np.float64)
        flat = t.reshape(-1)
        order = np.argsort(flat, kind="stable")
        ts = flat[order]
        k = self.wavenumber
        r_f = self._facet_spline(ts)
        out = np.zeros((len(ts), self.n_facets), dtype=np.complex128)
        lo, _ = _lerp_index(self.weight_times, ts)
        knots = slice(int(lo.min()), int(lo.max()) + 2)
        for g in self.groups:
            act = np.flatnonzero((g.weights[knots] != 0).any(0))  # only what is lit somewhere in this stretch
            if not act.size:
                continue
            fac = g.facet[act]
            splines = g.splines
            rel = (_spline_eval(splines[0], self.times, ts, act) - r_f[:, fac]).astype(np.float32)  # from the facet
            phase = np.float32(2 * k) * rel
            val = _lerp_eval(g.weights, self.weight_times, ts, act) * (np.cos(phase) + 1j * np.sin(phase))
            if g.kind == STRIP:  # along the cylinder (the exact factor across it is in the weight)
                a, b = (_spline_eval(c, self.times, ts, act).astype(np.float32) for c in splines[1:])
                val *= strip_along_factor(a, b)
            elif g.kind == TRIANGLE:
                a, b = (_spline_eval(c, self.times, ts, act).astype(np.float32) for c in splines[1:])
                val *= triangle_centroid_factor(a, b)
            out += _segments(val, fac, self.n_facets)
        res = np.empty_like(out)
        res[order] = out
        return res.reshape(t.shape + (self.n_facets,))

    def subset(self, keep: np.ndarray) -> SurfaceTracks:
        """The tracks of the facets where ``keep`` (F,) is true (their elements and points only)."""
        new = np.cumsum(keep) - 1
        return SurfaceTracks(self.times, self.weight_times, self.wavenumber, [g.subset(keep, new) for g in self.groups],
                             self.facet_ranges[:, keep])


@dataclass
class ScatterTracks:
    """Scatterers at the physics rate: effective range (T, K) metres and complex amplitude (T, K) counts.

    kind: (K,) DIRECT / BOUNCE / STATIC; label: (K,) part name (``slot:part``) or path description.
    surface: when set, the first ``surface.n_facets`` columns are facet tracks whose amplitudes at
    any instant come from :meth:`SurfaceTracks.amplitudes` (``amplitudes`` holds them at ``times``);
    the other columns are point scatterers, amplitudes interpolated linearly.
    """

    times: np.ndarray
    ranges: np.ndarray
    amplitudes: np.ndarray
    kind: np.ndarray
    label: np.ndarray
    surface: SurfaceTracks | None = None

    @property
    def n_surface(self) -> int:
        return 0 if self.surface is None else self.surface.n_facets

    def select(self, mask: np.ndarray) -> ScatterTracks:
        """The columns where ``mask``; facet tracks are kept or dropped together."""
        mask = np.asarray(mask, bool)
        f = self.n_surface
        surface = self.surface
        if f:
            if mask[:f].all():
                pass
            elif not mask[:f].any():
                surface = None
            else:
                raise ValueError("select keeps all facet tracks or none; use SurfaceTracks.subset for some")
        return ScatterTracks(self.times, self.ranges[:, mask], self.amplitudes[:, mask], self.kind[mask],
                             self.label[mask], surface)

    @staticmethod
    def concat(parts: list[ScatterTracks]) -> ScatterTracks:
        """Columns side by side; a part with facet tracks must come first."""
        parts = [p for p in parts if p.kind.size]
        if any(p.surface is not None for p in parts[1:]):
            raise ValueError("only the first part of a concatenation may carry facet tracks")
        return ScatterTracks(parts[0].times, np.concatenate([p.ranges for p in parts], 1),
                             np.concatenate([p.amplitudes.astype(np.complex128) for p in parts], 1),
                             np.concatenate([p.kind for p in parts]), np.concatenate([p.label for p in parts]),
                             parts[0].surface)

    @cached_property
    def _range_spline(self) -> CubicSpline:
        return CubicSpline(self.times, self.ranges, axis=0)

    def at(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ranges (cubic spline) and complex amplitudes at ``times`` (any shape) -> (*times.shape, K):
        facet tracks from their elements, point scatterers interpolated linearly."""
        t = np.asarray(times, dtype=np.float64)
        flat = t.reshape(-1)
        if flat.min() < self.times[0] - 1e-9 or flat.max() > self.times[-1] + 1e-9:
            raise ValueError(f"times {flat.min():.4f}..{flat.max():.4f} s outside the tracks "
                             f"{self.times[0]:.4f}..{self.times[-1]:.4f} s")
        ranges = self._range_spline(flat)
        lo, frac = _lerp_index(self.times, flat)
        f = self.n_surface
        amps = np.empty((len(flat), self.kind.size), dtype=np.complex128)
        pts = self.amplitudes[:, f:]
        amps[:, f:] = pts[lo] * (1 - frac)[:, None] + pts[lo + 1] * frac[:, None]
        if f:
            amps[:, :f] = self.surface.amplitudes(flat)
        shape = t.shape + (self.kind.size,)
        return ranges.reshape(shape), amps.reshape(shape)
