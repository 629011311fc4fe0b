"""RadarWeightNet readout of a gap diagnosis: how much of the gap a learned per-bone weighting closes,
compared with the best physical effect, and which effect its learned weights resemble.

RadarWeightNet (handradar.models.radar_weight_net) is trained briefly on the calibration split with
the SSIM loss on the baseline simulator's cached slot profiles (handradar.sim.cache), by the one
RadarWeightNet training loop (handradar.synthesis.fit.fit_weight_net), then scored on the
evaluation split like a candidate (gap_closed with a paired-bootstrap 95 % CI, and the paired
bootstrap of its difference to the best physical effect). ``final_train_loss`` is 1 - SSIM of the
trained network on its training rows.

Weight correlation: for each candidate effect at its fitted values, the per-bone amplitude change
log(A_k,effect / A_k,baseline) at every skeleton step (A_k: root sum of squares of the radar-equation
amplitudes of bone slot k's reflection points) is correlated (Pearson,
over evaluation rows x steps x tracked bone slots, each row's mean removed from both since a row's
overall scale does not reach its normalised spectrogram) with the learned log weight log w_k.
Effects that change no bone's amplitude (palm, forearm, multipath add unweighted points; noise; a clock
offset) have no such correlation (null).

    rwn_readout(data, build, base, features, profiles, train_idx, eval_idx, before_ssim, candidates,
                cfg, progress=True) -> (report dict, evaluation spectrograms (n, doppler, columns))
    slot_amplitudes(sim, skeleton, mask, times, visibility) -> (B, T, 38) amplitude per bone slot
"""

from __future__ import annotations

import numpy as np
import torch

from handradar.gap.engine import merge
from handradar.metrics import (
    bootstrap_difference,
    bootstrap_gap_closed,
    per_example_mse,
    per_example_ssim,
)
from handradar.sim.cache import DatasetCaches, SlotProfileCache
from handradar.sim.factory import SimFactory
from handradar.sim.features import BoneFeatures
from handradar.sim.scatterers import N_SLOTS, radar_amplitude
from handradar.synthesis.fit import Phase, fit_weight_net, load_pairs, predict


def slot_amplitudes(sim, skeleton: torch.Tensor, mask: torch.Tensor, times: torch.Tensor,
                    visibility: torch.Tensor | None) -> torch.Tensor:
    """Amplitude of each bone slot (B, T, 38) at the skeleton steps: sqrt(sum of its points' A^2)."""
    ctx = sim.context(skeleton, mask, times=times, visibility=visibility)
    s = sim.scatterers(ctx)
    amp = radar_amplitude(s.rcs_m2, s.tx.norm(dim=-1), s.rx.norm(dim=-1), sim.radar.wavelength_m, sim.tx_power_w,
                          sim.gain_tx_dbi, sim.gain_rx_dbi) * s.gain
    bone = s.owner >= 0
    out = amp.new_zeros(*amp.shape[:2], N_SLOTS)
    return out.index_add(2, s.owner[bone], amp[..., bone] ** 2).sqrt()


def _centred(x: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    n = valid.flatten(1).sum(1).clamp_min(1).to(x.dtype)
    mean = (x * valid).flatten(1).sum(1) / n
    return (x - mean.reshape(-1, *[1] * (x.dim() - 1))) * valid


def _pearson(a: torch.Tensor, b: torch.Tensor, valid: torch.Tensor) -> float | None:
    a, b = _centred(a, valid)[valid], _centred(b, valid)[valid]
    if a.numel() < 3 or float(a.std()) < 1e-9 or float(b.std()) < 1e-9:
        return None
    return float(torch.corrcoef(torch.stack([a, b]))[0, 1])


def rwn_readout(data, build: SimFactory, base, features: BoneFeatures, profiles: SlotProfileCache,
                train_idx: np.ndarray, eval_idx: np.ndarray, before_ssim: np.ndarray, candidates: list, cfg,
                *, progress: bool = True) -> tuple[dict, np.ndarray]:
    sim = build(base)
    caches = DatasetCaches(features, data.rows.masks, data.rows.times, profiles)
    train = load_pairs(caches, data.measured, train_idx)
    h = int(cfg.rwn_hidden)
    net_kwargs = {"hidden": h, "fc": (h, max(h // 2, 8))}
    # the training loop of every RadarWeightNet fit (handradar.synthesis.fit), with a short schedule
    net = fit_weight_net(sim, train, phases=[Phase(int(cfg.rwn_epochs), float(cfg.rwn_lr), int(cfg.rwn_batch_size))],
                         seed=int(cfg.seed), net_kwargs=net_kwargs, progress=progress)
    final_loss = float(1.0 - per_example_ssim(train.targets, predict(sim, net, train)).mean())
    del train
    evaluation = load_pairs(caches, data.measured, eval_idx)
    spec = predict(sim, net, evaluation, batch_size=int(cfg.batch_size))
    with torch.no_grad():
        weights = [net(evaluation.features[i:i + cfg.batch_size], evaluation.masks[i:i + cfg.batch_size])
                   for i in range(0, len(evaluation), cfg.batch_size)]
    target = torch.as_tensor(data.measured)
    ssim = per_example_ssim(target[eval_idx], spec)
    mse = per_example_mse(target[eval_idx], spec)
    boot = bootstrap_gap_closed(before_ssim, ssim, n_boot=cfg.n_boot, seed=cfg.seed)
    out = {"ssim": float(ssim.mean()), "mse": float(mse.mean()), "gap_closed": boot.estimate,
           "ci95": [boot.ci95[0], boot.ci95[1]], "train_rows": int(len(train_idx)), "epochs": cfg.rwn_epochs,
           "final_train_loss": final_loss}
    if candidates:
        best = candidates[0]
        diff, ci = bootstrap_difference(before_ssim, ssim, best.ssim, n_boot=cfg.n_boot, seed=cfg.seed)
        out.update(best_effect=best.effect, best_effect_gap_closed=float(best.gap_closed),
                   minus_best_effect=float(diff), minus_best_effect_ci95=[float(ci[0]), float(ci[1])])
    masks = torch.as_tensor(data.rows.masks)
    times = torch.as_tensor(data.rows.times, dtype=torch.float64)
    # ---- which effect the learned weights resemble ------------------------------------------------
    logw = torch.log(torch.cat(weights).double().clamp_min(1e-12))  # (n, T, 38)
    sk = torch.as_tensor(data.rows.skeletons[eval_idx])
    m = masks[eval_idx]
    vis = None if data.rows.visibility is None else torch.as_tensor(data.rows.visibility[eval_idx])
    with torch.no_grad():
        a0 = slot_amplitudes(sim, sk, m, times, vis).double()
        corr: dict[str, float | None] = {}
        for c in candidates:
            a1 = slot_amplitudes(build(merge(base, {c.effect: c.params})), sk, m, times, vis).double()
            valid = (a0 > 0) & (a1 > 0)
            change = torch.log(torch.where(valid, a1, torch.ones_like(a1)) / torch.where(valid, a0, torch.ones_like(a0)))
            corr[c.effect] = _pearson(logw, change, valid)
    out["weight_correlation"] = corr
    known = {k: v for k, v in corr.items() if v is not None}
    out["most_correlated"] = max(known, key=known.get) if known else None
    return out, spec.numpy()
