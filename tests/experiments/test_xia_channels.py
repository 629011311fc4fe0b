"""experiments.xia_channels: the row centroid against a closed form, and the channels read beside the DTI rows."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from experiments.xia_channels import (
    CHANNELS,
    angle_sweep,
    channel_means,
    dominant_cycles,
    low_side_share,
    main,
    row_centroids,
)


def test_row_centroid_closed_form():
    image = np.zeros((40, 64))
    image[12, :] = 1.0
    image[20, 30:] = 3.0  # from column 30 on: (12 * 1 + 20 * 3) / 4 = 18
    assert row_centroids(image, (10, 40)) == pytest.approx([12.0, 18.0])


def test_dominant_cycles_closed_form():
    """A blob whose row follows 20 + 8 sin(2 pi n c / 64) over the 64 columns turns n times; a one-way sweep once."""
    images = np.zeros((4, 40, 64))
    cols = np.arange(64)
    for i, n in enumerate((1, 2, 3)):
        images[i, np.round(20 + 8 * np.sin(2 * np.pi * n * cols / 64)).astype(int), cols] = 1.0
    images[3, 30 - cols // 4, cols] = 1.0
    assert dominant_cycles(images).tolist() == [1, 2, 3, 1]


def test_angle_sweep_closed_form():
    """A blob on bin 40 of 64 up to column 20, then on bin 24: sin(angle) falls by 16 bins of 2 / 64, 0.5; a still one
    does not move."""
    images = np.zeros((2, 64, 64))
    images[0, 40, :20], images[0, 24, 20:] = 1.0, 1.0
    images[1, 33, :] = 1.0
    assert angle_sweep(images).tolist() == [-0.5, 0.0]


def test_low_side_share_closed_form():
    """Energy above the background: 3 units on row 5 and 1 on row 25, none counted in the band around row 15."""
    image = np.full((32, 10), 0.5)
    image[5, :4] += 3.0
    image[25, :4] += 1.0
    image[14:17, :] += 9.0  # the zero band
    assert low_side_share(image, 15) == pytest.approx(0.75)


def test_channels_beside_the_dti_rows(tmp_path, capsys):
    """A stand-in laid out as Xia et al.'s mirror: a class whose vertical-angle blob climbs over time."""
    for channel in ("DTI", *CHANNELS):
        for cls in ("up", "still"):
            folder = tmp_path / "ds" / "train" / channel / cls
            folder.mkdir(parents=True)
            for i in range(3):
                a = np.zeros((40, 64), np.float32)
                for col in range(64):
                    row = 30 - col // 4 if (channel == "VATI" and cls == "up") else 20
                    a[row, col] = 1.0
                np.save(folder / f"{i}.npy", a)
    manifest = {"format": "handradar.measured/1", "name": "x", "root": ".",
                "rows": {"layout": "ds/{split}/DTI/{class}/*.npy", "splits": {"train": "train", "A": "train"}},
                "axes": {"doppler": "rows"}, "radar": {"carrier_hz": 77e9},
                "classes": {"up": ["swipe_up"], "still": ["idle"]}}
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(manifest))
    means = channel_means(tmp_path / "m.yaml")
    up = row_centroids(means["up"]["VATI"])
    assert up == sorted(up, reverse=True) and up[0] - up[-1] > 8
    assert row_centroids(means["still"]["VATI"]) == pytest.approx([20.0] * 6)
    assert main(["--manifest", str(tmp_path / "m.yaml")]) == 0
    assert "| up | 28.0, 25.0, 23.0, 21.0, 19.0, 17.0 |" in capsys.readouterr().out  # row 30 - column // 4
    for f in (tmp_path / "ds" / "train" / "RTI" / "up").glob("*.npy"):
        f.unlink()
    assert main(["--manifest", str(tmp_path / "m.yaml")]) == 2
    assert "no RTI rows of class 'up'" in capsys.readouterr().err
