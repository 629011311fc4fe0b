"""Test doubles for the experiment framework: class-dependent fake datasets, fake providers, a tiny net.

Spectrograms of class c carry a Doppler band centred on row 4 + 6c whose position oscillates over
time with a class-dependent period, plus noise: separable, but not by a single pixel. The skeleton
of each row encodes its class (wrist x = 0.01 c m), so the fake providers synthesise from skeletons
the way the real simulator does, without reading labels.
"""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest
from lightning.pytorch.callbacks import Callback
from torch import nn

from handradar.data.hdf5 import open_writer
from handradar.provenance import config_hash
from handradar.radar.chain import ChainConfig
from handradar.radar.config import RadarConfig
from handradar.vocab import GESTURES

N_STEPS = 4
DEFAULT_CFG = """channelCfg 1 1 0
adcCfg 2 1
profileCfg 0 77 338.8 6 51.2 0 0 76.22 1 256 10000 0 0 30
chirpCfg 0 0 0 0 0 0 0 1
frameCfg 0 0 128 0 100 1 0
"""


def default_radar() -> RadarConfig:
    return RadarConfig.from_cfg_text(DEFAULT_CFG, "default.cfg")
SUBJECTS = ("s01", "s02", "s03", "s04")
ANGLES = (0, 30, -30)


def class_pattern(label: int, rng: np.random.Generator, noise: float = 0.08, shift: float = 0.0) -> np.ndarray:
    """A (64, 32) spectrogram in [0, 1] of class ``label``."""
    rows = np.arange(64)[:, None]
    cols = np.arange(32)[None, :]
    centre = 4 + 6 * label + 2.0 * np.sin(2 * np.pi * cols / (6 + label)) + shift + rng.normal(0, 0.5)
    spec = np.exp(-0.5 * ((rows - centre) / 1.5) ** 2) + noise * rng.random((64, 32))
    return np.clip(spec / spec.max(), 0, 1).astype(np.float32)


def skeleton_for(label: int, rng: np.random.Generator) -> np.ndarray:
    sk = rng.normal(0, 0.002, (N_STEPS, 2, 21, 3)).astype(np.float32)
    sk[:, 0, 0, 0] = 0.01 * label
    sk[:, :, :, 2] += 0.3
    return sk


def label_from_skeleton(sk: np.ndarray) -> int:
    return int(round(float(np.median(sk[:, 0, 0, 0])) / 0.01))


def write_fake_dataset(path: Path, *, per_class: int = 12, n_classes: int = 10, seed: int = 0,
                       classes: list[str] | None = None, meta: bool = True) -> Path:
    """A ``handradar.dataset/1`` file with ``per_class`` rows of each class and the full meta."""
    rng = np.random.default_rng(seed)
    classes = list(classes or GESTURES[:n_classes])
    radar, chain = default_radar(), ChainConfig()
    with open_writer(path, classes=classes, radar=radar, chain=chain, skeleton_rate_hz=2.5, n_steps=N_STEPS,
                     config_hash=config_hash("fake", seed, per_class, n_classes)) as w:
        for i in range(per_class):
            for c in range(len(classes)):
                m = {"gesture": classes[c], "subject": SUBJECTS[i % len(SUBJECTS)], "angle_deg": ANGLES[i % 3],
                     "hands": 1 if c < 6 else 2, "occlusion": bool(i % 2), "repetition": i,
                     "recording": f"{classes[c]}_{i:03d}"} if meta else {"recording": f"{classes[c]}_{i:03d}"}
                w.append(class_pattern(c, rng), c, skeleton_for(c, rng), np.ones((N_STEPS, 2), bool), 0.0, m)
    return path


def _write_rows(path: Path, x: np.ndarray, y: np.ndarray, sk: np.ndarray, classes: list[str], tag: str) -> Path:
    with open_writer(path, classes=classes, radar=default_radar(), chain=ChainConfig(), skeleton_rate_hz=2.5,
                     n_steps=sk.shape[1], config_hash=config_hash(tag)) as w:
        for i in range(len(y)):
            w.append(x[i], int(y[i]), sk[i], np.ones((sk.shape[1], 2), bool), 0.0, {"recording": f"syn_{i}"})
    return path


CALLS: list[dict] = []


def fake_provider(real_path: Path, rows: np.ndarray, mode: str, *, fit_rows: np.ndarray, seed: int,
                  cache_dir: Path) -> Path:
    """Synthesises one spectrogram per requested row from its skeleton (label read from the skeleton)."""
    assert mode in ("model", "enhanced")
    CALLS.append({"rows": np.asarray(rows), "mode": mode, "fit_rows": np.asarray(fit_rows), "seed": seed})
    with h5py.File(real_path, "r") as h5:
        sk = h5["skeletons"][()][np.asarray(rows)]
        classes = __import__("json").loads(h5.attrs["classes"])
    rng = np.random.default_rng([seed, 1 if mode == "model" else 2])
    y = np.asarray([label_from_skeleton(s) for s in sk], dtype=np.int64)
    x = np.stack([class_pattern(int(c), rng, noise=0.15 if mode == "model" else 0.08) for c in y])
    out = Path(cache_dir) / f"fake_{mode}_{seed}_{len(rows)}_{abs(hash(tuple(np.asarray(rows).tolist())))}.h5"
    return _write_rows(out, x, y, sk, classes, f"fake-{mode}")


def wrong_label_provider(real_path: Path, rows: np.ndarray, mode: str, *, fit_rows: np.ndarray, seed: int,
                         cache_dir: Path) -> Path:
    """Breaks the contract: labels shifted by one row."""
    path = fake_provider(real_path, rows, mode, fit_rows=fit_rows, seed=seed, cache_dir=cache_dir)
    with h5py.File(path, "a") as h5:
        h5["labels"][...] = np.roll(h5["labels"][()], 1)
    return path


EXTERNAL_CALLS: list[str] = []


def fake_external_provider(source_cfg, *, seed: int, cache_dir: Path) -> Path:
    """13 external classes (like SFINGE3D): class k uses the fake pattern of (k mod 10) shifted by k // 10 rows."""
    EXTERNAL_CALLS.append(str(source_cfg["name"]))
    names = [f"ext{k:02d}" for k in range(13)]
    rng = np.random.default_rng(seed)
    y = np.repeat(np.arange(13), 8)
    x = np.stack([class_pattern(int(k) % 10, rng, shift=3.0 * (k // 10)) for k in y])
    sk = np.stack([skeleton_for(int(k) % 10, rng) for k in y])
    return _write_rows(Path(cache_dir) / f"external_{source_cfg['name']}_{seed}.h5", x, y, sk, names, "fake-external")


def tiny_cnn(num_classes: int) -> nn.Module:
    """A small CNN with a linear ``fc`` head (like the ResNets), fast on CPU."""
    net = nn.Sequential()
    net.add_module("features", nn.Sequential(
        nn.Conv2d(1, 8, 3, padding=1), nn.BatchNorm2d(8), nn.ReLU(), nn.MaxPool2d(2),
        nn.Conv2d(8, 16, 3, padding=1), nn.BatchNorm2d(16), nn.ReLU(), nn.AdaptiveAvgPool2d((8, 4)), nn.Flatten()))
    net.add_module("fc", nn.Linear(16 * 8 * 4, num_classes))
    return net


class CrashOnce(Callback):
    """Raises at the end of training epoch ``epoch`` of the fit whose module logs under ``prefix``,
    unless ``marker`` exists (then creates it). Appends "<prefix> <epoch>" to ``epoch_log`` at the
    first batch of every epoch, so a test sees where a resumed fit started."""

    def __init__(self, epoch: int, marker: str, prefix: str, epoch_log: str) -> None:
        self.epoch, self.marker, self.prefix, self.epoch_log = epoch, Path(marker), prefix, Path(epoch_log)

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx) -> None:
        if batch_idx:
            return
        with open(self.epoch_log, "a") as fh:
            fh.write(f"{getattr(pl_module, 'prefix', '?')} {trainer.current_epoch}\n")

    def on_train_epoch_end(self, trainer, pl_module) -> None:
        if (getattr(pl_module, "prefix", None) == self.prefix and trainer.current_epoch == self.epoch
                and not self.marker.exists()):
            self.marker.write_text("crashed")
            raise RuntimeError(f"simulated crash after epoch {self.epoch}")


def fake_overrides(data: Path, tmp: Path, *, logger: str = "none", extra: tuple[str, ...] = ()) -> list[str]:
    """Overrides that point a train.py config at a fake dataset, fake providers, a tiny net and tmp paths."""
    return ["data=hdf5", f"data.path={data}", f"paths.log_dir={tmp}/logs", f"paths.cache_dir={tmp}/cache",
            "model.net._target_=tests.tasks.fakes.tiny_cnn", "~model.net.stem_stride",
            "~synth.provider.sim", "~synth.provider.phases", "~synth.provider.guard_folds",
            "synth.provider._target_=tests.tasks.fakes.fake_provider",
            "~synth.external_provider.radar", "~synth.external_provider.chain", "~synth.external_provider.sim",
            "synth.external_provider._target_=tests.tasks.fakes.fake_external_provider",
            "synth.fit_sim=none",  # fake skeletons cannot be simulated (tests/tasks/test_closed_loop.py fits)
            f"logger={logger}", "checkpoint_interval_s=0", "trainer.max_steps=20", "cgan.max_steps=20", "print_table=false",
            *extra]


def compose_train(overrides: list[str]):
    """The train.py config composed with Hydra's compose API (as the entry point would)."""
    from hydra import compose, initialize_config_dir

    from handradar.config import VERSION_BASE, config_dir

    with initialize_config_dir(config_dir=str(config_dir()), version_base=VERSION_BASE):
        return compose("train", overrides=overrides)


# ---- fixtures (imported by the conftest.py of tests/{config,experiments,tasks}) ----------------------
@pytest.fixture(scope="session")
def fake_data(tmp_path_factory) -> Path:
    """10 gestures x 8 rows with full meta (subjects, angles, hands, occlusion) and skeletons."""
    return write_fake_dataset(tmp_path_factory.mktemp("data") / "fake.h5", per_class=8)


def custom_job(job) -> dict[str, float]:
    """A job kind defined outside handradar.tasks.train (like a synthesis-fit job)."""
    job.tracker.log_metrics({"custom/epoch_metric": 0.5}, step=0)
    return {"test/ssim_model": float(job.real.x.mean()), "test/n_rows": float(len(job.real))}
