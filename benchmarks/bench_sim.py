"""Simulator throughput: synthetic spectrograms per second from skeleton windows.

- cold: everything from the skeleton: retargeting, ray-cast visibility and the per-bone features
  (HandModelConfig defaults), per-slot profiles, RadarWeightNet forward, weighted sum, chain; one
  window at a time, then 32 windows as ``handradar-synth`` runs them (bone features in 2 joblib
  processes of one thread each and slot profiles, each into a fresh cache; net and chain over
  batches read back from the cache), the figure a user's synthesis sees;
- cached: per-slot profiles (float16 cache layout, or float32 as DataLoader workers would hand
  them over) and features already in memory, per batch of 64: RadarWeightNet forward + linear
  upsampling to the chirp times + weighted sum + chain; for batches of two-hand and of one-hand
  windows (the cache's ``active`` flags skip the absent hand); the torch.compile'd weighted sum;
  one training step (forward + backward).

The cold figures break the window's time down: visibility alone (handradar.hand.visibility, the
hand model's stride and backend), the rest of the features, slot profiles, and net + weighted sum +
chain; each is the best of ``HANDRADAR_BENCH_COLD_REPEAT`` (default 3) passes over the windows.

Threads: HANDRADAR_BENCH_THREADS (default 2); HANDRADAR_BENCH_COMPILE=0 skips the compiled variant;
HANDRADAR_BENCH_SIM=cold (or cached) runs only that part (default: both).

Default radar and chain (1.6 s windows, 2048 chirps, 8 gated bins), skeletons at 100 Hz.
Run: ``PYTHONPATH=$PWD/src:$PWD python -m benchmarks bench_sim``.
"""

from __future__ import annotations

import os
import tempfile

import numpy as np
import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf

from benchmarks.common import Result, best_time
from handradar.hand.mesh import default_template
from handradar.hand.model import HandModelConfig
from handradar.hand.visibility import visibility
from handradar.metrics import fast_ssim_loss
from handradar.models.radar_weight_net import RadarWeightNet
from handradar.provenance import REPO_ROOT
from handradar.radar.chain import ChainConfig
from handradar.sim.cache import (
    DatasetCaches,
    SlotProfileCache,
    cache_slot_profiles,
    pack,
)
from handradar.sim.features import FEATURE_NAMES, bone_features, cached_bone_features
from handradar.sim.simulator import Simulator
from handradar.synthesis.fit import predict_cached
from tests.sim.demo import window

BATCH = 64


def _radar():
    return instantiate(OmegaConf.load(REPO_ROOT / "conf" / "radar" / "awr1843.yaml"))


def _cold(windows, times, radar, hand, sim, net) -> list[Result]:
    """Skeleton -> spectrogram with nothing cached, one window at a time, and where its time goes."""
    repeat = int(os.environ.get("HANDRADAR_BENCH_COLD_REPEAT", "3"))
    n = len(windows)

    def cold_one(pos, mask):
        f = bone_features(pos, times, mask, radar.wavelength_m, hand).features
        with torch.no_grad():
            sk, mk = torch.as_tensor(pos[None]), torch.as_tensor(mask[None])
            w = net(torch.as_tensor(f[None]), mk)
            return sim(sk, mk, w)

    template = default_template(hand.sections, hand.rings)
    joints = [hand.joints(p) for p, _ in windows]
    t_cold = best_time(lambda: [cold_one(*w) for w in windows], repeat=repeat) / n
    t_vis = best_time(lambda: [visibility(j, m, template=template, backend=hand.backend, stride=hand.visibility_stride)
                               for j, (_, m) in zip(joints, windows)], repeat=repeat) / n
    t_feat = best_time(lambda: [bone_features(p, times, m, radar.wavelength_m, hand) for p, m in windows],
                       repeat=repeat) / n
    sks = [torch.as_tensor(p[None]) for p, _ in windows]
    mks = [torch.as_tensor(m[None]) for _, m in windows]
    feats = [torch.as_tensor(bone_features(p, times, m, radar.wavelength_m, hand).features[None]) for p, m in windows]
    with torch.no_grad():
        t_prof = best_time(lambda: [sim.slot_profiles(s, m) for s, m in zip(sks, mks)], repeat=repeat) / n
        prof = [sim.slot_profiles(s, m) for s, m in zip(sks, mks)]
        t_rest = best_time(lambda: [sim.spectrogram(sim.combine(p, net(f, m))) for p, f, m in zip(prof, feats, mks)],
                           repeat=repeat) / n
    threads = torch.get_num_threads()
    return [Result("cold (features + profiles + net + chain)", 1.0 / t_cold, "spectrograms/s",
                   f"{threads} threads; half one-hand, half two-hand windows"),
            Result(f"cold: visibility ({hand.backend}, stride {hand.visibility_stride})", t_vis, "s/window",
                   f"{len(times)} steps, 1 or 2 hands"),
            Result("cold: features (visibility + retargeting + rcs + derivatives)", t_feat, "s/window"),
            Result("cold: slot profiles (closed-form range response)", t_prof, "s/window"),
            Result("cold: net + weighted sum + chain", t_rest, "s/window")]


def _cold_pipeline(times, radar, hand, sim, net, n_windows: int = 32, n_jobs: int = 2) -> Result:
    """Skeleton -> spectrogram for ``n_windows`` windows as ``handradar-synth`` runs them
    (synthesize_source): bone features in blocks of 16 rows over ``n_jobs`` joblib processes of one
    thread each, written to a fresh feature cache; slot profiles one window at a time into a fresh
    profile cache; then RadarWeightNet, weighted sum and chain over batches read back from it."""
    rows = [window(times, hands=1 + i % 2, seed=i) for i in range(n_windows)]
    pos, masks = np.stack([r[0] for r in rows]), np.stack([r[1] for r in rows])

    def pipeline(cache_dir):
        feats = cached_bone_features(pos, times, masks, radar.wavelength_m, hand, cache_dir, n_jobs=n_jobs)
        profiles = SlotProfileCache(cache_slot_profiles(sim, pos, masks, cache_dir, times=times))
        predict_cached(sim, net, DatasetCaches(feats, masks, times, profiles), np.arange(n_windows))

    repeat = int(os.environ.get("HANDRADAR_BENCH_COLD_REPEAT", "3"))
    with tempfile.TemporaryDirectory() as tmp:
        runs = iter(range(repeat + 1))  # fresh (cold) caches per timed run
        pipeline(f"{tmp}/warm")  # starts the worker processes
        t = best_time(lambda: pipeline(f"{tmp}/{next(runs)}"), repeat=repeat)
    return Result(f"cold, {n_windows} windows as synthesis runs them", n_windows / t, "spectrograms/s",
                  f"features in {n_jobs} processes x 1 thread, profiles per window into the cache, then net + chain "
                  f"in batches of 32 ({torch.get_num_threads()} threads)")


def run() -> list[Result]:
    threads = int(os.environ.get("HANDRADAR_BENCH_THREADS", "2"))
    torch.set_num_threads(threads)
    torch.manual_seed(0)
    radar, chain = _radar(), ChainConfig()
    hand = HandModelConfig()
    sim = Simulator(radar, chain, hand=hand)
    net = RadarWeightNet().eval()
    steps = int(round(chain.frames_per_window(radar) * radar.frame_period_s * sim.skeleton_rate_hz))
    times = np.arange(steps) / sim.skeleton_rate_hz
    out: list[Result] = []

    # ---- cold: skeleton -> spectrogram, one window at a time -----------------------------------------
    windows = [window(times, hands=h, seed=s) for s, h in enumerate((1, 2, 1, 2))]
    sk = torch.as_tensor(np.stack([w[0] for w in windows]))
    mk = torch.as_tensor(np.stack([w[1] for w in windows]))
    parts = os.environ.get("HANDRADAR_BENCH_SIM", "cold,cached").split(",")
    if "cold" in parts:
        out += _cold(windows, times, radar, hand, sim, net)
        out.append(_cold_pipeline(times, radar, hand, sim, net))
    if "cached" not in parts:
        return out

    # ---- cached: packed profiles + features in memory --------------------------------------------------
    with torch.no_grad():
        prof = sim.slot_profiles(sk, mk)
    packed, scale = pack(prof)
    feats = torch.stack([torch.as_tensor(bone_features(p, times, m, radar.wavelength_m, hand).features)
                         for p, m in windows])
    reps = BATCH // len(windows)
    bytes_per = packed[0].numel() * packed.element_size() + 4 + feats[0].numel() * 4 + mk[0].numel()
    for label, rows, dtype in (("two-hand", [1, 3], torch.float16), ("one-hand", [0, 2], torch.float16),
                               ("two-hand", [1, 3], torch.float32)):
        idx = torch.tensor(rows * (BATCH // 2))
        p_b, s_b, f_b, m_b = packed[idx].to(dtype).contiguous(), scale[idx], feats[idx], mk[idx]
        active = m_b.any(dim=(0, 1)).repeat_interleave(19)

        def cached():
            with torch.no_grad():
                w = net(f_b, m_b)
                return sim.spectrogram(sim.combine(p_b, w, scale=s_b, active=active))

        t = best_time(cached, repeat=5)
        how = ("float16 profiles as stored" if dtype == torch.float16
               else "float32 batches (converted in DataLoader workers)")
        out.append(Result(f"cached forward, {label} batches, {how}", BATCH / t, "spectrograms/s",
                          f"batch {BATCH}, {threads} threads: net + upsampling + weighted sum + chain"))
    del reps
    idx = torch.tensor([1, 3] * (BATCH // 2))
    if os.environ.get("HANDRADAR_BENCH_COMPILE", "1") == "1":
        fast = Simulator(radar, chain, hand=hand, compile_combine=True)
        p_b, s_b, f_b, m_b = packed[idx].contiguous(), scale[idx], feats[idx], mk[idx]

        def compiled():
            with torch.no_grad():
                return fast.spectrogram(fast.combine(p_b, net(f_b, m_b), scale=s_b))

        t_compile = best_time(compiled, repeat=1)  # the first call compiles
        t = best_time(compiled, repeat=5)
        out.append(Result("cached forward, two-hand, torch.compile'd weighted sum", BATCH / t, "spectrograms/s",
                          f"batch {BATCH}, {threads} threads; first call {t_compile:.0f} s (compilation)"))
    p_b, s_b, f_b, m_b = packed[idx].contiguous(), scale[idx], feats[idx], mk[idx]
    target = torch.rand(BATCH, chain.stft_len, chain.n_columns)
    train_net = RadarWeightNet()
    opt = torch.optim.Adam(train_net.parameters(), lr=1e-3)

    def step():
        loss = fast_ssim_loss(sim.spectrogram(sim.combine(p_b, train_net(f_b, m_b), scale=s_b)), target)
        opt.zero_grad()
        loss.backward()
        opt.step()

    t = best_time(step, repeat=3)
    out.append(Result("cached training step (forward + backward), two-hand", BATCH / t, "examples/s",
                      f"batch {BATCH}, fast_ssim_loss, Adam"))
    out.append(Result("cache memory per example", bytes_per / 2**20, "MiB",
                      f"39 slots x {packed.shape[2] * packed.shape[3] * packed.shape[4]} chirps x {packed.shape[5]} bins "
                      f"x 2 float16 + {len(FEATURE_NAMES)} features x {steps} steps x 38 float32"))
    return out
