"""Conditional-GAN training (the CGAN baseline of the few-shot experiments)."""

from __future__ import annotations

from collections.abc import Sequence

import lightning.pytorch as pl
import numpy as np
import torch
from torch.nn import functional as F

from handradar.models.cgan import Discriminator, Generator


class CGANModule(pl.LightningModule):
    """Non-saturating conditional GAN training with Adam; one D step then one G step per batch.

    ``max_steps`` of a Trainer counts optimizer steps: two per batch here. Logs
    ``<prefix>d_loss`` and ``<prefix>g_loss`` per epoch. real_label < 1 is one-sided label
    smoothing (Salimans et al.), which keeps the discriminator from saturating on tiny data.
    mismatch: also show the discriminator real spectrograms with wrong labels as fakes; on a few
    dozen examples the plain CGAN often learns to ignore the label, this makes it learn it.
    """

    def __init__(self, generator: Generator, discriminator: Discriminator, *, lr: float = 2e-4,
                 betas: Sequence[float] = (0.5, 0.999), real_label: float = 0.9, mismatch: bool = True,
                 prefix: str = "gan/") -> None:
        super().__init__()
        self.generator, self.discriminator = generator, discriminator
        self.lr, self.betas, self.real_label, self.prefix = lr, tuple(betas), real_label, prefix
        self.mismatch = mismatch
        self.automatic_optimization = False

    def training_step(self, batch: tuple[torch.Tensor, torch.Tensor], batch_idx: int) -> None:
        x, y = batch
        opt_g, opt_d = self.optimizers()
        z = torch.randn(len(y), self.generator.latent_dim, device=x.device)
        fake = self.generator(z, y)

        d_real = self.discriminator(x, y)
        d_fake = self.discriminator(fake.detach(), y)
        d_loss = (F.binary_cross_entropy_with_logits(d_real, torch.full_like(d_real, self.real_label))
                  + F.binary_cross_entropy_with_logits(d_fake, torch.zeros_like(d_fake)))
        if self.mismatch:
            # real spectrograms with a wrong label are fakes too (matching-aware discriminator,
            # Reed et al. 2016): the discriminator must read the label, so the generator must obey it
            wrong = (y + torch.randint(1, self.generator.num_classes, y.shape, device=y.device)) % self.generator.num_classes
            d_wrong = self.discriminator(x, wrong)
            d_loss = d_loss + F.binary_cross_entropy_with_logits(d_wrong, torch.zeros_like(d_wrong))
        opt_d.zero_grad()
        self.manual_backward(d_loss)
        opt_d.step()

        g_out = self.discriminator(fake, y)
        g_loss = F.binary_cross_entropy_with_logits(g_out, torch.ones_like(g_out))
        opt_g.zero_grad()
        self.manual_backward(g_loss)
        opt_g.step()

        self.log(f"{self.prefix}d_loss", d_loss, on_step=False, on_epoch=True, batch_size=len(y), sync_dist=True)
        self.log(f"{self.prefix}g_loss", g_loss, on_step=False, on_epoch=True, batch_size=len(y), sync_dist=True)

    def configure_optimizers(self):
        return (torch.optim.Adam(self.generator.parameters(), lr=self.lr, betas=self.betas),
                torch.optim.Adam(self.discriminator.parameters(), lr=self.lr, betas=self.betas))


def sample_per_class(generator: Generator, counts: dict[int, int], *, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``counts[c]`` generated spectrograms (N, 64, 32) of each class c, and their labels (N,)."""
    labels = np.concatenate([np.full(n, c, dtype=np.int64) for c, n in sorted(counts.items())]) \
        if counts else np.zeros(0, dtype=np.int64)
    if not len(labels):
        return np.zeros((0, *generator.shape[1:]), dtype=np.float32), labels
    x = generator.sample(torch.as_tensor(labels), seed=seed)
    return x[:, 0].cpu().numpy().astype(np.float32), labels
