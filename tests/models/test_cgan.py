"""Conditional GAN: shapes and range, reproducible sampling, and class-conditional samples after training."""

from __future__ import annotations

import lightning.pytorch as pl
import numpy as np
import pytest
import torch

from handradar.data.datamodule import ArrayRows, TrainingRowsDataModule
from handradar.models.cgan import Discriminator, Generator
from handradar.tasks.gan import CGANModule, sample_per_class
from handradar.training import StepSeed
from tests.tasks.fakes import class_pattern


def test_shapes_and_range():
    g, d = Generator(10), Discriminator(10)
    labels = torch.arange(10).repeat(2)
    x = g(torch.randn(20, g.latent_dim), labels)
    assert x.shape == (20, 1, 64, 32)
    assert x.min() >= 0 and x.max() <= 1
    assert d(x, labels).shape == (20,)


def test_sampling_reproducible_and_conditional_input():
    torch.manual_seed(0)
    g = Generator(4)
    labels = torch.tensor([0, 1, 2, 3])
    a, b = g.sample(labels, seed=5), g.sample(labels, seed=5)
    assert torch.equal(a, b) and not torch.equal(a, g.sample(labels, seed=6))
    # the same noise with another label gives another spectrogram: the label is an input
    assert not torch.allclose(g.sample(torch.zeros(4, dtype=torch.long), seed=5), a)
    assert g.training  # sampling restores the mode


def test_sample_per_class_counts():
    x, y = sample_per_class(Generator(5), {0: 3, 4: 2}, seed=1)
    assert x.shape == (5, 64, 32) and x.dtype == np.float32
    assert y.tolist() == [0, 0, 0, 4, 4]


@pytest.fixture(scope="module")
def trained_generator() -> tuple[Generator, np.ndarray]:
    """A CGAN with the default networks and learning rate (conf/model/cgan.yaml) trained for 600
    optimizer steps on 3 classes of distinct fake spectrograms (20 each), and the class means.
    (Smaller networks learn the conditioning less reliably, so the test uses the real defaults.)"""
    classes = [0, 4, 8]  # well separated Doppler bands
    rng = np.random.default_rng(0)
    y = np.repeat(np.arange(3), 20)
    x = np.stack([class_pattern(classes[c], rng) for c in y])
    pl.seed_everything(0, verbose=False)
    module = CGANModule(Generator(3), Discriminator(3), lr=2e-4)
    trainer = pl.Trainer(accelerator="cpu", max_steps=600, logger=False, enable_checkpointing=False,
                         enable_progress_bar=False, enable_model_summary=False, callbacks=[StepSeed(0)])
    trainer.fit(module, datamodule=TrainingRowsDataModule([ArrayRows(x, y)], batch_size=20, seed=0))
    means = np.stack([x[y == c].mean(0) for c in range(3)])
    return module.generator, means


@pytest.mark.slow  # ~5 s on an idle 2-core CPU, 13 s on a loaded one
def test_samples_are_class_conditional(trained_generator):
    gen, means = trained_generator
    x, y = sample_per_class(gen, {0: 30, 1: 30, 2: 30}, seed=3)
    assert x.min() >= 0 and x.max() <= 1
    dist = ((x[:, None] - means[None]) ** 2).mean(axis=(2, 3))  # (N, classes)
    nearest = dist.argmin(1)
    assert (nearest == y).mean() >= 0.9, np.bincount(nearest * 3 + y, minlength=9).reshape(3, 3)
    # and the samples resemble the data, not just the right side of a boundary
    assert dist[np.arange(len(y)), y].mean() < 0.5 * dist[np.arange(len(y)), (y + 1) % 3].mean()


def test_small_cgan_learns_class_conditioning_fast(seed=0):
    """The fast version of the class-conditioning test: the same training module on 16 x 8 patterns
    (the fake spectrograms at every 4th row and column) with a smaller generator and discriminator,
    300 optimizer steps (~2 s). Measured, seeds 0-2: all 90 samples nearest their own class mean,
    distance ratio 0.20-0.29; a generator that ignores its label scores 1/3."""
    shape = (1, 16, 8)
    rng = np.random.default_rng(seed)
    y = np.repeat(np.arange(3), 20)
    x = np.stack([class_pattern((0, 4, 8)[c], rng)[::4, ::4] for c in y])
    pl.seed_everything(seed, verbose=False)
    module = CGANModule(Generator(3, latent_dim=16, hidden=(64, 128, 256), shape=shape),
                        Discriminator(3, hidden=(128, 64), label_units=16, shape=shape), lr=2e-3)
    trainer = pl.Trainer(accelerator="cpu", max_steps=300, logger=False, enable_checkpointing=False,
                         enable_progress_bar=False, enable_model_summary=False, callbacks=[StepSeed(seed)])
    trainer.fit(module, datamodule=TrainingRowsDataModule([ArrayRows(x, y)], batch_size=20, seed=seed))
    means = np.stack([x[y == c].mean(0) for c in range(3)])
    labels = torch.arange(3).repeat_interleave(30)
    samples = module.generator.sample(labels, seed=3)[:, 0].numpy()
    assert samples.shape == (90, 16, 8) and samples.min() >= 0 and samples.max() <= 1
    dist = ((samples[:, None] - means[None]) ** 2).mean(axis=(2, 3))
    y_s = labels.numpy()
    assert (dist.argmin(1) == y_s).mean() >= 0.9
    assert dist[np.arange(90), y_s].mean() < 0.5 * dist[np.arange(90), (y_s + 1) % 3].mean()
