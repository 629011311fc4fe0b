"""The evidence for each class's motion in Xia et al.'s dataset: where its other channels put the hand over time.

    python -m experiments.xia_channels [--manifest conf/manifests/xia2021.yaml] [--root DIR] [--split train]

Per class, the class-mean image of the split's rows in each channel (VATI: vertical angle x time, RTI: range x
time, HATI: horizontal angle x time; the DTI's folders with DTI replaced by the channel's name), and its row
centroid (intensity-weighted mean row) at a few columns: a sweep across the beam moves the centroid of an
angle channel and leaves the range flat; a push or pull moves the range. Needs the whole mirror
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
COLUMNS = (10, 20, 28, 36, 44, 54)


def row_centroids(image: np.ndarray, columns: tuple[int, ...] = COLUMNS) -> list[float]:
    """Intensity-weighted mean row of each of ``columns`` of a (rows, columns) image."""
    rows = np.arange(image.shape[0])[:, None]
    cols = image[:, list(columns)].astype(np.float64)
    return list((rows * cols).sum(axis=0) / np.maximum(cols.sum(axis=0), 1e-12))


def channel_means(manifest: str | Path, root: str | Path | None = None, split: str = "train") -> dict[str, dict]:
    """{class: {channel: class-mean image}} of ``split``'s rows in every channel of :data:`CHANNELS`."""
    m = read_manifest(manifest, root)
    if "/DTI/" not in m.layout:
        raise FormatError(m.path, "rows.layout has no /DTI/ folder to swap for another channel")
    out: dict[str, dict] = {}
    for cls in m.classes:
        out[cls] = {}
        for channel in CHANNELS:
            other = type(m)(**{**m.__dict__, "layout": m.layout.replace("/DTI/", f"/{channel}/")})
            folder, _, files = class_files(other, m.splits[split], cls)
            if not files:
                raise FormatError(folder, f"no {channel} rows of class {cls!r}: fetch the whole mirror "
                                          "(handradar-fetch dataset=xia2021)")
            out[cls][channel] = np.mean([read_image(f).astype(np.float64) for f in files], axis=0)
    return out


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--manifest", default=str(REPO_ROOT / "conf" / "manifests" / "xia2021.yaml"))
    ap.add_argument("--root", default=None, help="the data root (default: the manifest's)")
    ap.add_argument("--split", default="train")
    args = ap.parse_args(argv)
    try:
        means = channel_means(args.manifest, args.root, args.split)
    except FormatError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"row centroid of each class-mean image at columns {', '.join(map(str, COLUMNS))} ({args.split} split)")
    print("| class | " + " | ".join(CHANNELS) + " |")
    print("|---|" + "---|" * len(CHANNELS))
    for cls, images in means.items():
        cells = [", ".join(f"{c:.1f}" for c in row_centroids(images[ch])) for ch in CHANNELS]
        print(f"| {cls} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
