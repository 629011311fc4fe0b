"""The evidence for each class's motion in Xia et al.'s dataset: where its other channels put the hand over time.

    python -m experiments.xia_channels [--manifest conf/manifests/xia2021.yaml] [--root DIR] [--split train]

Per class, the class-mean image of the split's rows in each channel (VATI: vertical angle x time, RTI: range x
time, HATI: horizontal angle x time; the DTI's folders with DTI replaced by the channel's name), and its row
centroid (intensity-weighted mean row) at a few columns: a sweep across the beam moves the centroid of an
angle channel and leaves the range flat; a push or pull moves the range. Then each row's cycles: the number of
periods over its columns at which the spectrum of its centroid series peaks (1-8), counted over the class's rows: a
circle turning n times moves the range and the angles n times. Then how far each row's hand sweeps across the beam:
the change of its angle images' brightest row from the first columns to the last, in sin(angle) under TI's angle-FFT
convention (N bins span sin(angle) from -1 to 1, 2 / N a bin): a sweep of chord c at distance d changes it by about
c / d. Needs the whole mirror
(``handradar-fetch dataset=xia2021``: every channel), not the DTI-only copy. Writes nothing.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from handradar.data.measured import class_files, read_image, read_manifest
from handradar.errors import FormatError
from handradar.provenance import REPO_ROOT

CHANNELS = ("VATI", "RTI", "HATI")
ZERO_BAND = 3  # rows either side of zero Doppler left out of the sides' energy (the band a trembling hand leaves)
COLUMNS = (10, 20, 28, 36, 44, 54)
SWEEP_ENDS = ((4, 16), (48, 60))  # the columns before and after the gesture (the rows centre it on column ~31)


def row_centroids(image: np.ndarray, columns: tuple[int, ...] = COLUMNS) -> list[float]:
    """Intensity-weighted mean row of each of ``columns`` of a (rows, columns) image."""
    rows = np.arange(image.shape[0])[:, None]
    cols = image[:, list(columns)].astype(np.float64)
    return list((rows * cols).sum(axis=0) / np.maximum(cols.sum(axis=0), 1e-12))


def dominant_cycles(images: np.ndarray, most: int = 8) -> np.ndarray:
    """Per image of (n, rows, columns): the number of periods (1..``most``) over its columns at which the magnitude
    spectrum of its row-centroid series peaks."""
    rows = np.arange(images.shape[1])[None, :, None]
    c = (rows * images).sum(axis=1) / np.maximum(images.sum(axis=1), 1e-12)
    spectrum = np.abs(np.fft.rfft(c - c.mean(axis=1, keepdims=True), axis=1))
    return np.argmax(spectrum[:, 1:most + 1], axis=1) + 1


def angle_sweep(images: np.ndarray, ends: tuple[tuple[int, int], ...] = SWEEP_ENDS) -> np.ndarray:
    """Per angle image of (n, bins, columns): the median brightest bin over the last ``ends`` columns less that over
    the first, in sin(angle) (TI's angle FFT: the bins span sin(angle) from -1 to 1, 2 / bins a bin)."""
    peak = images.argmax(axis=1).astype(np.float64)
    (a0, a1), (b0, b1) = ends
    return (np.median(peak[:, b0:b1], axis=1) - np.median(peak[:, a0:a1], axis=1)) * 2.0 / images.shape[1]


def low_side_share(dti: np.ndarray, zero_row: int, band: int = ZERO_BAND) -> float:
    """Of a (Doppler rows, columns) image's energy above its median (the background) more than ``band`` rows from
    ``zero_row``, the share on the low-index side."""
    e = np.clip(dti - np.median(dti), 0.0, None)
    low, high = e[:max(zero_row - band, 0)].sum(), e[zero_row + band + 1:].sum()
    return float(low / max(low + high, 1e-12))


def channel_rows(manifest: str | Path, root: str | Path | None = None, split: str = "train") -> dict[str, dict]:
    """{class: {channel: (n, rows, columns) images}} of ``split``'s rows: the DTI and every channel of :data:`CHANNELS`."""
    m = read_manifest(manifest, root)
    if "/DTI/" not in m.layout:
        raise FormatError(m.path, "rows.layout has no /DTI/ folder to swap for another channel")
    out: dict[str, dict] = {}
    for cls in m.classes:
        out[cls] = {}
        for channel in ("DTI", *CHANNELS):
            other = type(m)(**{**m.__dict__, "layout": m.layout.replace("/DTI/", f"/{channel}/")})
            folder, _, files = class_files(other, m.splits[split], cls)
            if not files:
                raise FormatError(folder, f"no {channel} rows of class {cls!r}: fetch the whole mirror "
                                          "(handradar-fetch dataset=xia2021)")
            out[cls][channel] = np.stack([read_image(f).astype(np.float64) for f in files])
    return out


def channel_means(manifest: str | Path, root: str | Path | None = None, split: str = "train") -> dict[str, dict]:
    """{class: {channel: class-mean image}} of ``split``'s rows in every channel of :data:`CHANNELS`."""
    return {cls: {ch: a.mean(axis=0) for ch, a in chans.items()} for cls, chans in channel_rows(manifest, root, split).items()}


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--manifest", default=str(REPO_ROOT / "conf" / "manifests" / "xia2021.yaml"))
    ap.add_argument("--root", default=None, help="the data root (default: the manifest's)")
    ap.add_argument("--split", default="train")
    args = ap.parse_args(argv)
    try:
        rows = channel_rows(args.manifest, args.root, args.split)
    except FormatError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"row centroid of each class-mean image at columns {', '.join(map(str, COLUMNS))} ({args.split} split)")
    print("| class | " + " | ".join(CHANNELS) + " |")
    print("|---|" + "---|" * len(CHANNELS))
    for cls, images in rows.items():
        cells = [", ".join(f"{c:.1f}" for c in row_centroids(images[ch].mean(axis=0))) for ch in CHANNELS]
        print(f"| {cls} | " + " | ".join(cells) + " |")
    print("\ncycles of each row's centroid series: the two most common counts, with their share of the rows")
    print("| class | " + " | ".join(CHANNELS) + " |")
    print("|---|" + "---|" * len(CHANNELS))
    for cls, images in rows.items():
        cells = []
        for ch in CHANNELS:
            counts = np.bincount(dominant_cycles(images[ch]))
            top = np.argsort(counts)[::-1][:2]
            cells.append(", ".join(f"{k} ({counts[k] / counts.sum():.0%})" for k in top if counts[k]))
        print(f"| {cls} | " + " | ".join(cells) + " |")
    print("\nangle sweep of each row (sin(angle), TI's convention): median |change| and its quartiles")
    print("| class | " + " | ".join(ch for ch in CHANNELS if ch != "RTI") + " |")
    print("|---|" + "---|" * (len(CHANNELS) - 1))
    for cls, images in rows.items():
        sweeps = [np.abs(angle_sweep(images[ch])) for ch in CHANNELS if ch != "RTI"]
        print(f"| {cls} | " + " | ".join(f"{np.median(a):.2f} ({np.percentile(a, 25):.2f}-{np.percentile(a, 75):.2f})"
                                          for a in sweeps) + " |")
    m = read_manifest(args.manifest, args.root)
    zero = int(round(m.zero_doppler if m.zero_doppler is not None else rows[next(iter(rows))]["DTI"].shape[1] // 2))
    print(f"\nshare of each class-mean DTI's energy on its low rows (more than {ZERO_BAND} rows from zero Doppler, row {zero})")
    print("| class | low-side share |")
    print("|---|---|")
    for cls, images in rows.items():
        print(f"| {cls} | {low_side_share(images['DTI'].mean(axis=0), zero):.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
