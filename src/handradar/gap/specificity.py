"""Specificity: does a candidate's credit come where its physics says it should?

An effect that explains a gap closes more of it in the rows where its physics acts most: occlusion
where fingers hide others, the antenna pattern away from boresight, multipath with two hands, a
sync offset where the hand moves fast in range, a palm return where the palm faces the radar. A
candidate whose gain is uniform across such a factor closes a generic gap instead (a floor, a
smoothing): a sign that its credit is not its own.

White receiver noise acts through no row factor but through pixels: it adds the same expected power
at every Doppler and time, so it alone can fill the pixels far from every simulated return (at the
baseline's floor, more than FAR_ROWS Doppler rows from any pixel above it); a closer of a generic gap
(a Doppler spread, a broad slow return) acts next to the simulated returns instead, and only makes
the far pixels worse. Its evidence is a within-row contrast over pixels (:func:`far_contrast`).

Every factor is computed from the rows' skeleton windows (and the visibility the occlusion
candidate needs), never from meta.json, so that recordings from any source have them:

    row_factors(rows) -> {factor: (N,) float}       off_boresight_deg, radial_speed_m_s, palm_facing,
                                                    two_hands, hidden_fraction (when visibility is there)
    EXPECTED_FACTOR: {effect: factor}               the factor each effect's physics acts through
    interaction(gain, high, n_boot, seed) -> dict   mean gain where the factor is high minus where it is low,
                                                    with a bootstrap 95 % CI (rows resampled within each group)
    specificity(effect, gain, factors, n_boot, seed) -> dict | None   (report key ``specificity`` of a candidate)
    PIXEL_FACTOR: {effect: factor}                  noise: far_from_returns
    far_pixels(before) -> (N, doppler, columns) bool   at the floor, > FAR_ROWS rows from any simulated return
    far_contrast(measured, before, after, n_boot, seed) -> dict | None   per row, the mean squared-residual
                                                    reduction over the far pixels minus over the others; its
                                                    mean over rows with a bootstrap 95 % CI
    pixel_specificity(effect, measured, before, after, n_boot, seed) -> dict | None   (the same report key)

Evidence reported next to gap_closed; it does not enter ``cause`` (letting it decide was tried and not
adopted: docs/gap_validation.md#tried-and-not-adopted).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import scipy.ndimage

from handradar.gap.engine import RowSet

# joint indices of handradar.hand.skeleton.JOINT_NAMES
_WRIST, _INDEX_MCP, _MIDDLE_MCP, _PINKY_MCP = 0, 5, 9, 17

EXPECTED_FACTOR: dict[str, str] = {
    "occlusion": "hidden_fraction",  # fingers hidden behind others
    "antenna_pattern": "off_boresight_deg",  # gain falls off away from boresight (z)
    "multipath": "two_hands",  # hand-to-hand paths need two hands
    "sync_offset": "radial_speed_m_s",  # a time shift moves Doppler where the range rate is high
    "palm": "palm_facing",  # the palm plate returns most when it faces the radar
}
PIXEL_FACTOR: dict[str, str] = {
    "noise": "far_from_returns",  # white noise alone fills the pixels far from every simulated return
}
MIN_GROUP = 3  # rows per group below which no interaction is reported
FLOOR = 1e-6  # a baseline pixel at or below this ([0, 1] spectrogram) is at the chain's floor
FAR_ROWS = 4  # Doppler rows from a simulated return beyond which only noise acts: twice the Hamming mainlobe's half-width


def _masked_mean(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Mean over steps and hands of ``values`` (N, T, 2) where ``mask`` (N, T, 2) holds; 0 where none does."""
    m = mask.astype(np.float64)
    return (values * m).sum(axis=(1, 2)) / np.maximum(m.sum(axis=(1, 2)), 1.0)


def row_factors(rows: RowSet) -> dict[str, np.ndarray]:
    """Per-row factors from the skeleton windows (radar at the origin, boresight +z; metres, seconds)."""
    sk = np.asarray(rows.skeletons, dtype=np.float64)  # (N, T, 2, 21, 3)
    mask = np.asarray(rows.masks, dtype=bool)  # (N, T, 2)
    centre = sk[..., [_WRIST, _INDEX_MCP, _MIDDLE_MCP, _PINKY_MCP], :].mean(axis=-2)  # palm centre (N, T, 2, 3)
    rng = np.linalg.norm(centre, axis=-1)
    cos_off = np.clip(centre[..., 2] / np.maximum(rng, 1e-9), -1.0, 1.0)
    normal = np.cross(sk[..., _INDEX_MCP, :] - sk[..., _WRIST, :], sk[..., _PINKY_MCP, :] - sk[..., _WRIST, :])
    normal /= np.maximum(np.linalg.norm(normal, axis=-1, keepdims=True), 1e-12)
    facing = np.abs((normal * centre).sum(-1)) / np.maximum(rng, 1e-9)  # |cos| between palm normal and line of sight
    times = np.asarray(rows.times, dtype=np.float64)
    rate = np.abs(np.gradient(rng, times, axis=1)) if len(times) > 1 else np.zeros_like(rng)
    out = {"off_boresight_deg": _masked_mean(np.degrees(np.arccos(cos_off)), mask),
           "radial_speed_m_s": _masked_mean(rate, mask & np.roll(mask, 1, axis=1) & np.roll(mask, -1, axis=1)),
           "palm_facing": _masked_mean(facing, mask),
           "two_hands": (mask.all(axis=2).mean(axis=1) > 0.5).astype(np.float64)}
    if rows.visibility is not None:  # (N, T, 2, bones) visible fraction
        hidden = 1.0 - np.asarray(rows.visibility, dtype=np.float64).mean(axis=-1)
        out["hidden_fraction"] = _masked_mean(hidden, mask)
    return out


def interaction(gain: np.ndarray, high: np.ndarray, *, n_boot: int = 2000, seed: int = 0) -> dict | None:
    """Mean ``gain`` where ``high`` minus where not, with a 95 % bootstrap CI (each group resampled on
    its own); None when a group has fewer than MIN_GROUP rows."""
    gain = np.asarray(gain, dtype=np.float64)
    high = np.asarray(high, dtype=bool)
    a, b = gain[high], gain[~high]
    if len(a) < MIN_GROUP or len(b) < MIN_GROUP:
        return None
    rng = np.random.default_rng(seed)
    boots = (a[rng.integers(0, len(a), (n_boot, len(a)))].mean(1)
             - b[rng.integers(0, len(b), (n_boot, len(b)))].mean(1))
    lo, hi = np.percentile(boots, [2.5, 97.5])
    return {"gain_high": float(a.mean()), "gain_low": float(b.mean()), "contrast": float(a.mean() - b.mean()),
            "ci95": [float(lo), float(hi)], "n_high": int(len(a)), "n_low": int(len(b))}


def specificity(effect: str, gain: np.ndarray, factors: Mapping[str, np.ndarray], *, n_boot: int = 2000,
                seed: int = 0) -> dict | None:
    """The interaction of ``effect``'s per-row gain (its SSIM minus the baseline's) with the factor its
    physics acts through, split at the factor's median (two_hands: two hands against one); None for an
    effect with no such factor, or where the data cannot split it."""
    factor = EXPECTED_FACTOR.get(effect)
    if factor is None or factor not in factors:
        return None
    values = np.asarray(factors[factor], dtype=np.float64)
    high = values > 0.5 if factor == "two_hands" else values > np.median(values)
    split = "two hands vs one" if factor == "two_hands" else f"above vs at or below the median {float(np.median(values)):.4g}"
    return _evidence(factor, split, interaction(gain, high, n_boot=n_boot, seed=seed))


def _evidence(factor: str, split: str, out: dict | None) -> dict | None:
    """A contrast as report key ``specificity``: specific when its 95 % CI lies above 0."""
    return None if out is None else {"factor": factor, "split": split, **out, "specific": bool(out["ci95"][0] > 0.0)}


def far_pixels(before: np.ndarray) -> np.ndarray:
    """(N, doppler, columns) bool: pixels of the baseline spectrograms ``before`` more than FAR_ROWS Doppler
    rows (circularly) from every pixel above the floor in their column."""
    above = np.asarray(before) > FLOOR
    near = scipy.ndimage.maximum_filter1d(above.astype(np.uint8), size=2 * FAR_ROWS + 1, axis=1, mode="wrap")
    return near == 0


def far_contrast(measured: np.ndarray, before: np.ndarray, after: np.ndarray, *, n_boot: int = 2000,
                 seed: int = 0) -> dict | None:
    """Where a candidate's credit lies in the pixels: per row, the mean reduction of the squared residual
    (measured - simulated, [0, 1] spectrograms (N, doppler, columns)) from ``before`` (baseline) to ``after``
    (candidate) over the pixels far from every simulated return (:func:`far_pixels`), minus over the other
    pixels; the mean over rows with a bootstrap 95 % CI (rows resampled). None when fewer than MIN_GROUP
    rows have both kinds."""
    m, b, a = (np.asarray(x, dtype=np.float64) for x in (measured, before, after))
    gain = ((m - b) ** 2 - (m - a) ** 2).reshape(len(m), -1)
    far = far_pixels(b).reshape(len(m), -1)
    n_far = far.sum(axis=1)
    both = (n_far > 0) & (n_far < far.shape[1])
    if both.sum() < MIN_GROUP:
        return None
    g, f, nf = gain[both], far[both], n_far[both]
    far_gain = (g * f).sum(axis=1) / nf
    near_gain = (g * ~f).sum(axis=1) / (f.shape[1] - nf)
    diff = far_gain - near_gain
    rng = np.random.default_rng(seed)
    boots = diff[rng.integers(0, len(diff), (n_boot, len(diff)))].mean(axis=1)
    lo, hi = np.percentile(boots, [2.5, 97.5])
    return {"gain_high": float(far_gain.mean()), "gain_low": float(near_gain.mean()), "contrast": float(diff.mean()),
            "ci95": [float(lo), float(hi)], "n_rows": int(both.sum()), "far_share": float(nf.mean() / f.shape[1])}


def pixel_specificity(effect: str, measured: np.ndarray, before: np.ndarray, after: np.ndarray, *,
                      n_boot: int = 2000, seed: int = 0) -> dict | None:
    """:func:`far_contrast` for an effect whose physics acts through pixels (PIXEL_FACTOR), in the form of
    :func:`specificity`'s result; None for other effects or where no row has both kinds of pixel."""
    if effect not in PIXEL_FACTOR:
        return None
    split = (f"within each row, the pixels more than {FAR_ROWS} Doppler rows from every simulated return vs the "
             "others (squared-residual reduction)")
    return _evidence(PIXEL_FACTOR[effect], split, far_contrast(measured, before, after, n_boot=n_boot, seed=seed))
