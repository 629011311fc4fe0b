"""Fitting RadarWeightNet to measured spectrograms: the paper's hybrid synthesis (Table I).

Per row, the network-independent parts (per-bone features, per-slot range profiles) come from the
caches of :func:`handradar.sim.cache.cache_dataset`; a training step is then only

    features -> RadarWeightNet -> weights (B, T, 38) -> Simulator.combine (weighted slot sum at the
    chirp times) -> Simulator.spectrogram (the shared chain) -> 1 - SSIM against the measurement.

The paper's optimisation set-up is a list of phases (Adam; lr 5e-4, batch 32, 20 epochs; then
lr 1e-4, batch 16, 50 epochs): the learning rate changes at phase boundaries and the training
loader is rebuilt every epoch with the phase's batch size. Shuffling depends only on (seed, epoch).

Public API:

    Phase(epochs, lr, batch_size);  PAPER_SCHEDULE;  schedule(config phases) -> tuple[Phase, ...]
    Pairs / load_pairs(caches, targets (N, 64, 32), rows) -> Pairs     in-memory training data
    PairsDataModule(train: Pairs, phases, seed)                          the training batches
    SynthFitModule(sim, net, phases)                                     the LightningModule
    fit_weight_net(sim, train: Pairs, *, phases, seed, ...) -> RadarWeightNet   the one training loop
    guarded_weight_net(sim, train: Pairs, labels, *, folds, ...) -> (Shrunk, report)   fitted with held-out rows
    choose_shrink(model, held) -> (shrink, report)                         its rule, from per-row held-out SSIM
    Shrunk(net, shrink)                                                    weights 1 + shrink (w - 1)
    predict(sim, net | None, pairs, batch_size=32) -> (N, 64, 32)         None: modelling only
    predict_cached(sim, net | None, caches, rows, batch_size=32) -> (N, 64, 32)   streamed from the caches
    synth_scores(sim, net, pairs) -> {"ssim_model", "ssim_enhanced", "mse_model", "mse_enhanced"}
    save_weight_net(path, net, sim, net_kwargs) / load_weight_net(path) -> (net, info)
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import lightning.pytorch as pl
import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf
from torch.utils.data import DataLoader, Dataset

from handradar.atomic import atomic_path
from handradar.data.datamodule import EpochSeededSampler
from handradar.errors import FormatError
from handradar.data.splits import stratified_partition
from handradar.metrics import bootstrap_gap_closed, fast_ssim_loss, per_example_mse, per_example_ssim
from handradar.models.radar_weight_net import RadarWeightNet
from handradar.sim.cache import DatasetCaches, unpack
from handradar.sim.simulator import Simulator
from handradar.training import EpochStartCheckpoint, StepSeed


@dataclass(frozen=True)
class Phase:
    """One stage of the optimisation schedule."""

    epochs: int
    lr: float
    batch_size: int


PAPER_SCHEDULE = (Phase(20, 5e-4, 32), Phase(50, 1e-4, 16))
WEIGHTS_FORMAT = "handradar.radarweightnet/1"  # checkpoints of save_weight_net


@dataclass
class Pairs:
    """Rows of a dataset held in memory: network inputs, cached slot profiles and targets."""

    rows: np.ndarray  # (N,) row indices into the dataset file
    features: torch.Tensor  # (N, T, 2, 19, 5) float32
    masks: torch.Tensor  # (N, T, 2) bool
    profiles: torch.Tensor  # (N, 39, F, L, Ch, bins) complex64 slot profiles (5 MB a row by default)
    active: torch.Tensor  # (N, 38) bool: bone slots that reflect anything
    targets: torch.Tensor  # (N, 64, 32) float32 measured spectrograms in [0, 1]

    def __len__(self) -> int:
        return len(self.rows)

    def subset(self, idx: np.ndarray | torch.Tensor) -> Pairs:
        i = torch.as_tensor(np.asarray(idx), dtype=torch.long)
        return Pairs(self.rows[i.numpy()], self.features[i], self.masks[i], self.profiles[i], self.active[i],
                     self.targets[i])


def load_pairs(caches: DatasetCaches, targets: np.ndarray | None, rows: np.ndarray, *, features: bool = True) -> Pairs:
    """Gather ``rows`` of the cached features/profiles and their measured spectrograms.

    Profiles are unpacked to complex64 once here (twice the cache's float16 size in memory): a
    training step then spends no time converting them. ``targets`` None (nothing measured) and
    ``features`` False (modelling only) leave those fields empty.
    """
    rows = np.asarray(rows, dtype=np.int64)
    packed, scale, active = caches.profiles.load(rows)
    feats = (torch.as_tensor(caches.features.features[rows], dtype=torch.float32) if features
             else torch.zeros(len(rows), 0))
    tgt = torch.zeros(len(rows), 0) if targets is None else torch.as_tensor(np.asarray(targets)[rows], dtype=torch.float32)
    return Pairs(rows=rows, features=feats, masks=torch.as_tensor(caches.masks[rows], dtype=torch.bool),
                 profiles=unpack(packed, scale), active=torch.as_tensor(active, dtype=torch.bool), targets=tgt)


def _spectrograms(sim: Simulator, net: RadarWeightNet | None, p: Pairs) -> torch.Tensor:
    weights = None if net is None else net(p.features, p.masks)
    return sim.render(p.profiles, weights, active=p.active.any(0))


@torch.no_grad()
def predict(sim: Simulator, net: RadarWeightNet | None, pairs: Pairs, batch_size: int = 32) -> torch.Tensor:
    """Simulated spectrograms (N, 64, 32) of ``pairs``: modelling only when ``net`` is None."""
    if net is not None:
        net.eval()
    out = [_spectrograms(sim, net, pairs.subset(np.arange(i, min(i + batch_size, len(pairs)))))
           for i in range(0, len(pairs), batch_size)]
    return torch.cat(out)


@torch.no_grad()
def predict_cached(sim: Simulator, net: RadarWeightNet | None, caches: DatasetCaches, rows: np.ndarray,
                   batch_size: int = 32) -> torch.Tensor:
    """Simulated spectrograms (N, 64, 32) of cache ``rows``, read batch by batch: the profiles stay
    float16 as stored (Simulator.render scales them), so memory holds one batch, not N rows
    unpacked to complex64 (5 MB each: 14 GB for DHG 14/28's 2800 sequences)."""
    if net is not None:
        net.eval()
    rows = np.asarray(rows, dtype=np.int64)
    out = []
    for i in range(0, len(rows), batch_size):
        sel = rows[i:i + batch_size]
        packed, scale, active = caches.profiles.load(sel)
        weights = None if net is None else net(torch.as_tensor(caches.features.features[sel], dtype=torch.float32),
                                               torch.as_tensor(caches.masks[sel], dtype=torch.bool))
        out.append(sim.render(packed, weights, active=active.any(0), scale=scale))
    return torch.cat(out) if out else torch.zeros(0, sim.chain.n_doppler, sim.chain.n_columns)


def synth_scores(sim: Simulator, net: RadarWeightNet, pairs: Pairs) -> dict[str, float]:
    """Table I: SSIM and MSE against the measurement, modelling only vs modelling + RadarWeightNet."""
    out = {}
    for name, n in (("model", None), ("enhanced", net)):
        pred = predict(sim, n, pairs)
        out[f"ssim_{name}"] = float(per_example_ssim(pairs.targets, pred).mean())
        out[f"mse_{name}"] = float(per_example_mse(pairs.targets, pred).mean())
    return out


def _checked(phases: Sequence[Phase | dict]) -> tuple[Phase, ...]:
    if not phases:
        raise ValueError("the optimisation schedule needs at least one phase")
    return tuple(p if isinstance(p, Phase) else Phase(**p) for p in phases)


def phase_of(phases: Sequence[Phase], epoch: int) -> Phase:
    """The schedule's phase of ``epoch`` (the last phase after the schedule's end)."""
    for p in phases:
        if epoch < p.epochs:
            return p
        epoch -= p.epochs
    return phases[-1]


class _PairRows(Dataset):
    def __init__(self, pairs: Pairs) -> None:
        self.pairs = pairs

    def __len__(self) -> int:
        return len(self.pairs)

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        p = self.pairs
        return {"row": torch.tensor(int(p.rows[i])), "features": p.features[i], "masks": p.masks[i],
                "profiles": p.profiles[i], "active": p.active[i], "targets": p.targets[i]}


class PairsDataModule(pl.LightningDataModule):
    """RadarWeightNet's training batches: rows of the dataset caches (features, slot profiles) with their
    measured spectrograms, in the order of EpochSeededSampler (seed, epoch), at the batch size of each
    epoch's phase (the trainer reloads the loader every epoch)."""

    def __init__(self, train: Pairs, phases: Sequence[Phase] = PAPER_SCHEDULE, seed: int = 0) -> None:
        super().__init__()
        self.train, self.phases, self.seed = train, _checked(phases), int(seed)

    def train_dataloader(self) -> DataLoader:
        epoch = self.trainer.current_epoch if self.trainer is not None else 0
        n = len(self.train)
        return DataLoader(_PairRows(self.train), batch_size=min(phase_of(self.phases, epoch).batch_size, n),
                          sampler=EpochSeededSampler(n, self.seed))


class SynthFitModule(pl.LightningModule):
    """Trains RadarWeightNet (the simulator is fixed) with the SSIM loss, phase by phase."""

    def __init__(self, sim: Simulator, net: RadarWeightNet, phases: Sequence[Phase] = PAPER_SCHEDULE) -> None:
        super().__init__()
        self.sim, self.net, self.phases = sim, net, _checked(phases)
        self.sim.requires_grad_(False)

    @property
    def total_epochs(self) -> int:
        return sum(p.epochs for p in self.phases)

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        p = Pairs(rows=batch["row"].numpy(), **{k: v for k, v in batch.items() if k != "row"})
        loss = fast_ssim_loss(_spectrograms(self.sim, self.net, p), p.targets)
        self.log("synth/train_loss", loss, on_step=False, on_epoch=True, batch_size=len(p))
        return loss

    def configure_optimizers(self):
        opt = torch.optim.Adam(self.net.parameters(), lr=self.phases[0].lr)
        lr0 = self.phases[0].lr
        sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda epoch: phase_of(self.phases, epoch).lr / lr0)
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "epoch"}}


def schedule(phases: Sequence[Phase | dict] | None) -> tuple[Phase, ...]:
    if phases is None:
        return PAPER_SCHEDULE
    out = []
    for p in phases:
        if isinstance(p, Phase):
            out.append(p)
        else:
            d = OmegaConf.to_container(p) if isinstance(p, DictConfig) else dict(p)
            out.append(Phase(int(d["epochs"]), float(d["lr"]), int(d["batch_size"])))
    return tuple(out)


def fit_weight_net(sim: Simulator, train: Pairs, *, phases: Sequence[Phase] = PAPER_SCHEDULE, seed: int = 0,
                   trainer_kwargs: dict | None = None, ckpt_dir: str | Path | None = None,
                   net_kwargs: dict | None = None, callbacks: Sequence[pl.Callback] = (),
                   logger: Any = False, progress: bool = False) -> RadarWeightNet:
    """Train a fresh RadarWeightNet on ``train`` with the SSIM loss (resumable with ``ckpt_dir``): the
    one training loop of every RadarWeightNet fit (synth_fit, the enhanced variants, the diagnosis readout)."""
    pl.seed_everything(seed, verbose=False)
    net = RadarWeightNet(**(net_kwargs or {}))
    module = SynthFitModule(sim, net, phases)
    data = PairsDataModule(train, phases, seed)
    cbs = [*callbacks, StepSeed(seed)]
    if ckpt_dir is not None:
        cbs.append(EpochStartCheckpoint(ckpt_dir))
    kw = {"accelerator": "cpu", "devices": 1, "deterministic": True, "enable_progress_bar": bool(progress),
          "enable_model_summary": False, "num_sanity_val_steps": 0, "log_every_n_steps": 1, **(trainer_kwargs or {})}
    trainer = pl.Trainer(max_epochs=module.total_epochs, reload_dataloaders_every_n_epochs=1, logger=logger,
                         enable_checkpointing=False, callbacks=cbs,
                         default_root_dir=str(ckpt_dir) if ckpt_dir else None, **kw)
    last = Path(ckpt_dir) / "last.ckpt" if ckpt_dir is not None else None
    trainer.fit(module, datamodule=data, ckpt_path=str(last) if last is not None and last.is_file() else None)
    return net.eval()


class Shrunk(torch.nn.Module):
    """A RadarWeightNet whose weights are pulled toward 1 (the modelling-only simulator): 1 + shrink (w - 1),
    shrink in [0, 1] (0: modelling only; 1: the network as trained)."""

    def __init__(self, net: RadarWeightNet, shrink: float) -> None:
        super().__init__()
        if not 0.0 <= shrink <= 1.0:
            raise ValueError(f"shrink must be in [0, 1], found {shrink}")
        self.net, self.shrink = net, float(shrink)

    def forward(self, features: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        return 1.0 + self.shrink * (self.net(features, mask) - 1.0)


SHRINKS = (0.0, 0.25, 0.5, 0.75, 1.0)
GUARD_RULE = "best shrink if its CI clears 0"  # in the synthetic files' cache key: a new rule never reuses old files


def choose_shrink(model: np.ndarray, held: dict[float, np.ndarray], *, n_boot: int = 1000,
                  seed: int = 0) -> tuple[float, dict]:
    """The shrink a guarded RadarWeightNet applies, from per-row held-out SSIM: ``model`` of the
    modelling-only simulator, ``held[s]`` of the network shrunk by s. The shrink with the highest mean
    is kept only when its held-out gain (gap_closed against ``model``, 95 % paired-bootstrap CI) has a
    CI above 0; otherwise 0, the modelling-only simulator: a gain the rows cannot tell from noise is not
    worth the network's risk (docs/configuration.md#training-jobs)."""
    means = {lam: float(v.mean()) for lam, v in held.items()}
    best = max(held, key=lambda lam: (means[lam], -lam))  # ties: the smaller shrink
    gain = bootstrap_gap_closed(model, held[max(held)], n_boot=n_boot, seed=seed)
    chosen = bootstrap_gap_closed(model, held[best], n_boot=n_boot, seed=seed)
    shrink = best if best > 0 and chosen.ci95[0] > 0 else 0.0
    return shrink, {"heldout_ssim": {str(lam): m for lam, m in means.items()}, "shrink": shrink,
                    "shrink_best_ssim": best, "gain": gain.estimate, "gain_ci95": list(gain.ci95),
                    "gain_chosen": chosen.estimate, "gain_chosen_ci95": list(chosen.ci95)}


def guarded_weight_net(sim: Simulator, train: Pairs, labels: np.ndarray, *, folds: int = 2,
                       shrinks: Sequence[float] = SHRINKS, phases: Sequence[Phase] = PAPER_SCHEDULE, seed: int = 0,
                       net_kwargs: dict | None = None, n_boot: int = 1000) -> tuple[Shrunk, dict]:
    """RadarWeightNet that knows when it does not help: ``folds`` networks, each trained on the other
    folds of ``train`` (stratified by ``labels``), score every shrink toward weight 1 on their held-out
    rows; :func:`choose_shrink` picks the shrink (the best held-out SSIM, when its gain's CI clears 0),
    which is applied to one more network trained on all rows. Shrink 0 is the modelling-only simulator,
    and then no final network is trained.

    The report: :func:`choose_shrink`'s (per shrink the held-out mean SSIM; the applied ``shrink`` and the
    best by SSIM; ``gain``: the held-out gap_closed [95 % CI] of the unshrunk network, 1 - SSIM of the
    modelling-only simulator being the gap; ``gain_chosen`` of the best shrink, optimistic: chosen on those
    rows), with ``folds`` and ``rows``."""
    labels = np.asarray(labels)
    parts = stratified_partition(labels, [1.0 / folds] * folds, seed, every_part=True)
    held = {lam: np.zeros(len(train)) for lam in shrinks}
    for j, test in enumerate(parts):
        net = fit_weight_net(sim, train.subset(np.setdiff1d(np.arange(len(train)), test)), phases=phases,
                             seed=seed + j + 1, net_kwargs=net_kwargs)
        held_out = train.subset(test)
        for lam in shrinks:
            held[lam][test] = per_example_ssim(held_out.targets, predict(sim, Shrunk(net, lam), held_out))
    model = held[0.0] if 0.0 in held else per_example_ssim(train.targets, predict(sim, None, train))
    shrink, choice = choose_shrink(model, held, n_boot=n_boot, seed=seed)
    report = {"folds": folds, "rows": len(train), **choice}
    net = fit_weight_net(sim, train, phases=phases, seed=seed, net_kwargs=net_kwargs) if shrink > 0 else \
        RadarWeightNet(**(net_kwargs or {})).eval()
    return Shrunk(net, shrink).eval(), report


def save_weight_net(path: str | Path, net: RadarWeightNet, sim: Simulator, net_kwargs: dict | None = None) -> Path:
    """A RadarWeightNet checkpoint that ``synth.weights=`` / :func:`load_weight_net` read back."""
    with atomic_path(path) as tmp:
        torch.save({"format": WEIGHTS_FORMAT, "net_kwargs": dict(net_kwargs or {}), "state_dict": net.state_dict(),
                    "hand": asdict(sim.hand), "skeleton_rate_hz": sim.skeleton_rate_hz}, tmp)
    return Path(path)


def load_weight_net(path: str | Path) -> tuple[RadarWeightNet, dict]:
    """(network in eval mode, checkpoint info) from :func:`save_weight_net`'s file."""
    path = Path(path)
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except (OSError, RuntimeError, ValueError) as exc:
        raise FormatError(path, f"not a readable RadarWeightNet checkpoint ({exc})") from None
    if not isinstance(ckpt, dict) or ckpt.get("format") != WEIGHTS_FORMAT:
        raise FormatError(path, f"expected a {WEIGHTS_FORMAT} checkpoint (written by synth_fit), "
                                f"found {ckpt.get('format') if isinstance(ckpt, dict) else type(ckpt).__name__}")
    net = RadarWeightNet(**ckpt["net_kwargs"])
    net.load_state_dict(ckpt["state_dict"])
    return net.eval(), ckpt
