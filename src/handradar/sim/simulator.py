"""The differentiable simulator: skeleton window -> per-bone signals -> weighted sum -> spectrogram.

Pipeline of one batch (every step torch, differentiable end to end):

    skeleton (B, T, 2, 21, 3) at times (T,) relative to the window start
      -> skeleton-stage effects (tracking_jitter, sync_offset)
      -> untracked steps of a partly tracked hand hold its last tracked pose (hold_untracked)
      -> standard-hand retargeting (handradar.hand.retarget; HandModelConfig.retarget)
      -> one scattering centre per bone at its midpoint, cylinder RCS (sim.scatterers)
      -> scatterer-stage effects (palm, forearm, occlusion, multipath, antenna_pattern)
      -> per-slot range profiles at the true chirp times (sim.profiles)      (B, 39, F, L, Ch, bins)
      -> weighted sum with RadarWeightNet weights (or 1)                      (B, F, L, Ch, bins)
      -> signal-stage effects (noise)
      -> handradar.radar.chain.spectrogram_from_profiles: the chain of the measured data (B, 64, 32),
         with the slots' cross terms kept in the share ``coherence``

The window starts at a frame boundary, so its chirp times are ``radar.chirp_times_s(frames)``
with frames = chain.frames_per_window(radar); the skeleton times default to
``arange(T) / skeleton_rate_hz`` (the dataset rows of handradar.data.examples).

Build simulators with :class:`handradar.sim.factory.SimFactory` (the ``sim`` config, overrides
at construction); the constructor below is what it calls.

Public API:

    Simulator(radar, chain, *, hand=HandModelConfig(), effects=(), effect_params=None,
              skeleton_rate_hz=100.0, tx_power_w=0.0158, gain_tx_dbi=10.5, gain_rx_dbi=10.5,
              rcs_exponent=1.0, metacarpal_gain=1.0, coherence=1.0, compile_combine=False)
      rcs_exponent: aspect exponent of every cylinder's RCS (handradar.sim.rcs; 1 = the paper's)
      metacarpal_gain: amplitude factor of the four finger metacarpals' reflection points (1 = the
            paper's cylinders; 0 = none, as if the palm's flesh buried them): a generic knob of
            step 0, since wrist-to-knuckle cylinders are the hand model's crudest part
      coherence: the share of the slots' cross terms kept in the chain's power (1 = the paper's
            coherent sum; 0 = the sum of each slot's own power). Relative phases between bones
            depend on their ranges to a fraction of the 3.9 mm wavelength, far below what a skeleton
            tracker resolves: a 0.5 mm change of the reference world's finger radius changes its
            spectrograms as much as its palm does. With phase errors of independent slots,
            E[exp(i phi)] = rho, the expected power is rho^2 |sum s_k|^2 + (1 - rho^2) sum |s_k|^2:
            coherence = rho^2 (Gaussian errors of std sigma: exp(-sigma^2)). Each bone slot is one
            surface, and slot 38 (palm, forearm, multipath) one more part
      compile_combine: torch.compile the weighted sum (see profiles.combine_slots)
      .forward(skeleton, mask, weights=None, *, times=None, visibility=None) -> (B, doppler, columns)
      .slot_profiles(skeleton, mask, *, times=None, visibility=None, arm=None) -> (B, 39, F, L, Ch, bins) complex
            network-independent: cache these (sim.cache) and train RadarWeightNet on them
      .combine(slot_profiles, weights=None, *, times=None, active=None, scale=None) -> (B, F, L, Ch, bins)
            weights (B, T, 38) positive at the skeleton steps (slot = hand * 19 + bone),
            upsampled linearly in time to the chirp times
      .slot_power(slot_profiles, weights=None, *, times=None, active=None, scale=None) -> (B, doppler, columns)
            the sum of each slot's own chain power (the incoherent part; same arguments as combine)
      .spectrogram(signal, slot_power=None) -> (B, doppler, columns) in [0, 1] (signal effects, then
            the chain); slot_power is needed when coherence < 1
      .render(slot_profiles, weights=None, *, times=None, active=None, scale=None) -> (B, doppler, columns)
            spectrogram(combine(...), slot_power(...)): what every caller with slot profiles uses
      .summed_rows(skeletons, masks, *, times=None, arms=None) -> ((B, F, L, Ch, bins) complex, slot power | None)
      .render_rows(skeletons, masks, *, times=None, arms=None, batch_size=32, progress=False) -> (N, doppler, columns)
            modelling only, window by window, with no slot-profile cache (synthesis without RadarWeightNet);
            arms: (N, T, 2, 2, 3) elbows and shoulders where the source has them (the motion library), for forearm
      .effect(name) -> the Effect instance;  .effects: nn.ModuleList in pipeline order
      .key() -> dict of everything that determines the output (cache keys)
      .chirp_times (F, L, C) float64 buffer, seconds
      .context(skeleton, mask, *, times, visibility, arm=None) -> SimContext (retargeted joints, ...) for effects
      .scatterers(ctx) -> Scatterers (bones + scatterer-stage effects);  .profiles_of(scat, times) -> slot profiles
    slot 38 of the profiles holds the unweighted reflectors (palm, forearm, multipath's bone-to-bone
    bounces). With the cache's float16 real view pass its ``scale``.
    skeleton: (B, T, 2, 21, 3) metres radar frame; mask (B, T, 2) bool (untracked hands reflect nothing);
    visibility: optional (B, T, 2, 19) visible/facing fraction from the feature cache (the occlusion
    effect ray casts it itself when absent).

Amplitude defaults: TX power 12 dBm (AWR1843 data sheet), 10.5 dBi per antenna (AWR1843BOOST
patch array); they set absolute levels only (the noise effect sets its level from an SNR and the
spectrogram is normalised to its peak).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from handradar.hand.mesh import bone_radii
from handradar.hand.model import HandModelConfig
from handradar.hand.retarget import retarget, standard_lengths
from handradar.radar.chain import ChainConfig, power_to_unit, profile_power
from handradar.radar.config import RadarConfig
from handradar.sim import effects as _effects  # noqa: F401  (registers the eight effects)
from handradar.sim.effects.base import Effect, SimContext, build_effects
from handradar.sim.interp import upsample_to_chirps
from handradar.sim.profiles import combine_slots, scatterer_profiles, window_chirp_times
from handradar.sim.scatterers import (
    METACARPAL_SLOTS,
    N_SLOTS,
    Scatterers,
    bone_scatterers,
)

_SUMMED_STEP = 8  # windows summed_rows simulates together at coherence 1: fewer, larger torch ops (make bench)


def hold_untracked(positions: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Untracked steps of a partly tracked hand take the pose of the nearest earlier tracked step
    (else the next one), so that interpolation to the chirp times never sweeps a hand through the
    origin (its amplitude is faded by the mask instead); never-tracked hands stay zero."""
    b, t = mask.shape[:2]
    steps = torch.arange(t, device=mask.device).reshape(1, t, 1).expand(b, t, 2)
    last = torch.cummax(torch.where(mask, steps, torch.full_like(steps, -1)), dim=1).values
    nxt = torch.flip(torch.cummin(torch.flip(torch.where(mask, steps, torch.full_like(steps, t)), [1]), dim=1).values, [1])
    src = torch.where(last >= 0, last, nxt.clamp(max=t - 1))  # (B, T, 2)
    held = torch.gather(positions, 1, src[..., None, None].expand_as(positions))
    held = torch.where(mask.any(dim=1, keepdim=True)[..., None, None], held, torch.zeros_like(held))
    return torch.where(mask[..., None, None], positions, held)


class Simulator(nn.Module):
    """Cylinder-mesh hand reflection model of Tang et al. plus optional effects (module doc)."""

    def __init__(self, radar: RadarConfig, chain: ChainConfig, *, hand: HandModelConfig | None = None,
                 effects: list | tuple = (), effect_params: dict | None = None, skeleton_rate_hz: float = 100.0,
                 tx_power_w: float = 0.0158, gain_tx_dbi: float = 10.5, gain_rx_dbi: float = 10.5,
                 rcs_exponent: float = 1.0, metacarpal_gain: float = 1.0, coherence: float = 1.0,
                 compile_combine: bool = False) -> None:
        super().__init__()
        self.radar, self.chain = radar, chain
        self.hand = hand if isinstance(hand, HandModelConfig) else HandModelConfig(**dict(hand or {}))
        self.skeleton_rate_hz = float(skeleton_rate_hz)
        self.tx_power_w, self.gain_tx_dbi, self.gain_rx_dbi = float(tx_power_w), float(gain_tx_dbi), float(gain_rx_dbi)
        self.compile_combine = bool(compile_combine)
        self.rcs_exponent = float(rcs_exponent)
        if not 0.0 <= self.rcs_exponent <= 1.0:
            raise ValueError(f"rcs_exponent must be in [0, 1] (1: the paper's cylinder RCS), found {rcs_exponent}")
        self.metacarpal_gain = float(metacarpal_gain)
        if not 0.0 <= self.metacarpal_gain <= 1.0:
            raise ValueError(f"metacarpal_gain must be in [0, 1] (1: the paper's cylinders), found {metacarpal_gain}")
        self.coherence = float(coherence)
        if not 0.0 <= self.coherence <= 1.0:
            raise ValueError(f"coherence must be in [0, 1] (1: the paper's coherent sum), found {coherence}")
        self.effects = nn.ModuleList(build_effects(list(effects), dict(effect_params or {})))
        self.register_buffer("chirp_times", torch.as_tensor(window_chirp_times(radar, chain), dtype=torch.float64),
                             persistent=False)
        self.register_buffer("radii", torch.as_tensor(bone_radii(), dtype=torch.float32), persistent=False)
        self.register_buffer("lengths", torch.as_tensor(standard_lengths(self.hand.hand_scale), dtype=torch.float32),
                             persistent=False)

    # ---- helpers -------------------------------------------------------------------------------
    def key(self) -> dict:
        """Everything that determines this simulator's output, for cache keys (handradar.provenance.config_hash)."""
        return {"radar": self.radar, "chain": self.chain, "hand": self.hand.key(), "skeleton_rate_hz": self.skeleton_rate_hz,
                "amplitude": (self.tx_power_w, self.gain_tx_dbi, self.gain_rx_dbi), "rcs_exponent": self.rcs_exponent,
                **({"metacarpal_gain": self.metacarpal_gain} if self.metacarpal_gain != 1.0 else {}),
                **({"coherence": self.coherence} if self.coherence != 1.0 else {}),
                "effects": [(e.name, e.values(), e.settings()) for e in self.effects]}

    def effect(self, name: str) -> Effect:
        for e in self.effects:
            if e.name == name:
                return e
        raise KeyError(f"effect {name!r} is not in this simulator (has {[e.name for e in self.effects]})")

    def _stage(self, stage: str) -> list[Effect]:
        return [e for e in self.effects if e.stage == stage]

    def default_times(self, n_steps: int) -> torch.Tensor:
        """Skeleton step times (T,) seconds from the window start."""
        return torch.arange(n_steps, dtype=torch.float64, device=self.chirp_times.device) / self.skeleton_rate_hz

    def _check(self, skeleton: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        skeleton = torch.as_tensor(skeleton, device=self.chirp_times.device)
        mask = torch.as_tensor(mask, device=self.chirp_times.device).bool()
        if skeleton.dim() != 5 or skeleton.shape[2:] != (2, 21, 3) or mask.shape != skeleton.shape[:3]:
            raise ValueError(f"expected skeleton (B, T, 2, 21, 3) and mask (B, T, 2), found "
                             f"{tuple(skeleton.shape)} and {tuple(mask.shape)}")
        if not skeleton.is_floating_point():
            skeleton = skeleton.float()
        return skeleton, mask

    # ---- the pipeline ------------------------------------------------------------------------------
    def context(self, skeleton: torch.Tensor, mask: torch.Tensor, *, times: torch.Tensor | None = None,
                visibility: torch.Tensor | None = None, arm: torch.Tensor | None = None) -> SimContext:
        """Skeleton-stage effects and retargeting: the context the scatterer effects see (``arm``: (B, T, 2, 2, 3)
        elbows and shoulders, passed on as they are)."""
        skeleton, mask = self._check(skeleton, mask)
        times = self.default_times(skeleton.shape[1]) if times is None else torch.as_tensor(
            times, dtype=torch.float64, device=skeleton.device)
        for e in self._stage("skeleton"):
            skeleton, mask, times = e.apply_skeleton(skeleton, mask, times)
        skeleton = hold_untracked(skeleton, mask)
        joints = retarget(skeleton, self.lengths.to(skeleton.dtype)) if self.hand.retarget else skeleton
        if visibility is not None:
            visibility = torch.as_tensor(visibility, dtype=skeleton.dtype, device=skeleton.device)
        if arm is not None:
            arm = torch.as_tensor(arm, dtype=joints.dtype, device=joints.device)
            if arm.shape != (*joints.shape[:3], 2, 3):
                raise ValueError(f"expected arm (B, T, 2, 2, 3) beside skeleton {tuple(joints.shape)}, found {tuple(arm.shape)}")
        return SimContext(joints, mask, times, visibility, self.radar, self.chain, self.hand, self.rcs_exponent, arm)

    def slot_profiles(self, skeleton: torch.Tensor, mask: torch.Tensor, *, times: torch.Tensor | None = None,
                      visibility: torch.Tensor | None = None, arm: torch.Tensor | None = None) -> torch.Tensor:
        """Per-slot range profiles (B, 39, F, L, Ch, bins): 38 bone slots + 1 unweighted slot."""
        ctx = self.context(skeleton, mask, times=times, visibility=visibility, arm=arm)
        return self._profiles(ctx)

    def scatterers(self, ctx: SimContext) -> Scatterers:
        """The reflection points of a context: the bones', then the scatterer-stage effects."""
        scat = bone_scatterers(ctx.joints, ctx.mask, self.radar.wavelength_m, self.radii, self.rcs_exponent)
        if self.metacarpal_gain != 1.0:
            scat = scat.slots_scaled(METACARPAL_SLOTS, self.metacarpal_gain)
        for e in self._stage("scatterers"):
            scat = e.apply_scatterers(scat, ctx)
        return scat

    def profiles_of(self, scat: Scatterers, times: torch.Tensor, summed: bool = False) -> torch.Tensor:
        """Per-slot range profiles (B, 39, F, L, Ch, bins) of reflection points at skeleton ``times``
        (``summed``: their sum (B, F, L, Ch, bins), built without the slots)."""
        return scatterer_profiles(scat, times, self.chirp_times, self.radar, self.chain, tx_power_w=self.tx_power_w,
                                  gain_tx_dbi=self.gain_tx_dbi, gain_rx_dbi=self.gain_rx_dbi, summed=summed)

    def _profiles(self, ctx: SimContext) -> torch.Tensor:
        return self.profiles_of(self.scatterers(ctx), ctx.times)

    def step_times(self, n_steps: int, times: torch.Tensor | None = None) -> torch.Tensor:
        """Radar-clock times of the skeleton steps after the skeleton-stage effects (a clock offset
        moves them), so that weights stay attached to the poses they were computed from."""
        times = self.default_times(n_steps) if times is None else torch.as_tensor(
            times, dtype=torch.float64, device=self.chirp_times.device)
        dummy = torch.zeros(1, n_steps, 2, 21, 3, device=self.chirp_times.device)
        mask = torch.ones(1, n_steps, 2, dtype=torch.bool, device=self.chirp_times.device)
        for e in self._stage("skeleton"):
            dummy, mask, times = e.apply_skeleton(dummy, mask, times)
        return times

    def upsample(self, weights: torch.Tensor, times: torch.Tensor | None = None) -> torch.Tensor:
        """Weights (B, T, 38) at the skeleton steps -> (B, 38, F, L, C) at the chirp times."""
        if weights.dim() != 3 or weights.shape[-1] != N_SLOTS:
            raise ValueError(f"weights must be (B, T, {N_SLOTS}), found {tuple(weights.shape)}")
        return upsample_to_chirps(weights, self.step_times(weights.shape[1], times), self.chirp_times)

    def combine(self, slot_profiles: torch.Tensor, weights: torch.Tensor | None = None, *,
                times: torch.Tensor | None = None, active: torch.Tensor | None = None,
                scale: torch.Tensor | None = None) -> torch.Tensor:
        """Weighted sum of the slots (B, F, L, Ch, bins); weights (B, T, 38) at the skeleton steps
        (``times`` as given to slot_profiles, before any clock offset). slot_profiles may be the
        complex tensor or the cache's float16 real view with its per-row ``scale`` (B,);
        ``active`` (38,) skips slots that are zero in the whole batch."""
        w = None if weights is None else self.upsample(weights, times)
        out = combine_slots(slot_profiles, w, self.radar.n_rx, active, compiled=self.compile_combine)
        return out if scale is None else out * scale.to(out.real.dtype).reshape(-1, 1, 1, 1, 1)

    def slot_power(self, slot_profiles: torch.Tensor, weights: torch.Tensor | None = None, *,
                   times: torch.Tensor | None = None, active: torch.Tensor | None = None,
                   scale: torch.Tensor | None = None, unweighted: bool = True) -> torch.Tensor:
        """The sum of each slot's own chain power (B, doppler, columns): the spectrogram's power when
        the slots' relative phases are unknown (their cross terms average out). Arguments as
        :meth:`combine`; ``unweighted=False`` leaves slot 38 out. Slot by slot, so no (B, 39, ...)
        temporary."""
        real = torch.view_as_real(slot_profiles) if slot_profiles.is_complex() else slot_profiles
        acc = torch.float64 if real.dtype == torch.float64 else torch.float32
        w = None if weights is None else self.upsample(weights, times).repeat_interleave(self.radar.n_rx, dim=-1)
        keep = [k for k in range(N_SLOTS) if active is None or bool(active[k])] + ([N_SLOTS] if unweighted else [])
        power = None
        for k in keep:
            p = torch.view_as_complex(real[:, k].to(acc).contiguous())
            if w is not None and k < N_SLOTS:
                p = p * w[:, k, ..., None].to(acc)
            pk = profile_power(p, self.chain)
            power = pk if power is None else power + pk
        if scale is not None:
            power = power * scale.to(power.dtype).reshape(-1, 1, 1) ** 2
        return power

    def spectrogram(self, signal: torch.Tensor, slot_power: torch.Tensor | None = None) -> torch.Tensor:
        """Summed signal -> signal-stage effects -> the shared chain -> (B, doppler, columns) in [0, 1].

        A stochastic signal effect with ``draws`` > 1 (noise) is drawn that many times and the chain's
        power averaged before dB; with ``draws`` = 0 its expected power is added in closed form
        (``expected_power``, the limit of many draws): the expected spectrogram either way.

        With coherence c < 1, ``slot_power`` (:meth:`slot_power` of the slots summed into ``signal``)
        replaces the share 1 - c of the signal's own power. A signal effect's addition n (noise, the only
        signal effect, adds to the signal) has a phase unrelated to the slots', so the power shown is
        c |S + n|^2 + (1 - c)(sum |s_k|^2 + |n|^2): expected value c |S|^2 + (1 - c) sum |s_k|^2 + |n|^2,
        and never negative in a draw (the cross term 2 Re(S n*) of |S + n|^2 alone can exceed the rest
        where the slots' own power is small). The noise's SNR is relative to that shown power: its level
        is scaled by the shown total over |S|^2's, row by row."""
        c = self.coherence
        scale = None
        if c < 1.0:
            if slot_power is None:
                raise ValueError("coherence < 1 needs the slots' own power: Simulator.render, or spectrogram(signal, "
                                 "slot_power(...))")
            own = profile_power(signal, self.chain)
            shown = c * own + (1.0 - c) * slot_power.to(own.dtype)
            total = own.sum(dim=(-2, -1))
            scale = torch.where(total > 0, shown.sum(dim=(-2, -1)) / total.clamp_min(1e-30), torch.ones_like(total))
        stage = self._stage("signal")
        drawn = [e for e in stage if getattr(e, "draws", 1) > 0]
        draws = max([e.draws for e in drawn if hasattr(e, "draws")] + [1])
        s = signal
        if drawn:
            power = 0.0
            for _ in range(draws):
                s = signal
                for e in drawn:
                    s = e.apply_signal(s, self.radar, self.chain, scale)
                if c < 1.0:
                    power = power + c * profile_power(s, self.chain) + (1.0 - c) * profile_power(s - signal, self.chain)
                else:
                    power = power + profile_power(s, self.chain)
            power = power / draws
            if c < 1.0:
                power = power + (1.0 - c) * slot_power.to(power.dtype)
        else:
            power = shown if c < 1.0 else profile_power(signal, self.chain)
        for e in stage:
            if e not in drawn:  # after the drawn ones (noise, order 80, is the last signal effect)
                power = power + e.expected_power(s, self.radar, self.chain, scale)
        return power_to_unit(power, self.chain)

    def render(self, slot_profiles: torch.Tensor, weights: torch.Tensor | None = None, *,
               times: torch.Tensor | None = None, active: torch.Tensor | None = None,
               scale: torch.Tensor | None = None) -> torch.Tensor:
        """Slot profiles -> spectrogram (B, doppler, columns): :meth:`combine`, then :meth:`spectrogram`
        with the slots' own power when coherence < 1. Arguments as :meth:`combine`."""
        signal = self.combine(slot_profiles, weights, times=times, active=active, scale=scale)
        power = None if self.coherence >= 1.0 else self.slot_power(slot_profiles, weights, times=times,
                                                                     active=active, scale=scale)
        return self.spectrogram(signal, power)

    @torch.no_grad()
    def summed_rows(self, skeletons: torch.Tensor, masks: torch.Tensor, *, times: torch.Tensor | None = None,
                    arms: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Modelling only: each window's reflection points simulated and summed, (B, F, L, Ch, bins) complex, and
        when coherence < 1 the slots' own power (B, doppler, columns), else None. One window at a time, as the
        slot-profile cache is filled (sim.cache), but nothing is stored; at coherence 1 no slot is built, and
        ``_SUMMED_STEP`` windows go at a time (the points' sum is formed inside the range response)."""
        signals, powers = [], []
        step = 1 if self.coherence < 1.0 else _SUMMED_STEP
        for i in range(0, skeletons.shape[0], step):
            ctx = self.context(skeletons[i:i + step], masks[i:i + step], times=times,
                               arm=None if arms is None else arms[i:i + step])
            if self.coherence < 1.0:
                prof = self._profiles(ctx)
                signals.append(self.combine(prof))
                powers.append(self.slot_power(prof))
            else:
                signals.append(self.profiles_of(self.scatterers(ctx), ctx.times, summed=True))
        return torch.cat(signals), torch.cat(powers) if powers else None

    @torch.no_grad()
    def render_rows(self, skeletons: torch.Tensor | np.ndarray, masks: torch.Tensor | np.ndarray, *,
                    times: torch.Tensor | np.ndarray | None = None, arms: torch.Tensor | np.ndarray | None = None,
                    batch_size: int = 32, progress: bool = False) -> torch.Tensor:
        """Modelling-only spectrograms (N, doppler, columns) of N windows, without the slot-profile cache
        (skeletons (N, T, 2, 21, 3) metres, masks (N, T, 2), times (T,) seconds, arms (N, T, 2, 2, 3) elbows and
        shoulders or None: tensors or arrays).

        :meth:`summed_rows` of ``batch_size`` windows at a time, then the signal effects and the chain on each
        batch: the rows and draws of :meth:`render` on the cache's batches, less its float16 rounding, and no
        39 slots a row written (2.5 MB at 4096 chirps) that nothing reads again. (Worker processes were slower
        than torch's own threads on 2 cores: docs/architecture.md.)"""
        skeletons, masks = torch.as_tensor(skeletons), torch.as_tensor(masks)
        arms = None if arms is None else torch.as_tensor(arms)
        batches = [slice(i, i + batch_size) for i in range(0, skeletons.shape[0], batch_size)]
        if progress:
            from tqdm import tqdm
            batches = tqdm(batches, desc=f"spectrograms ({batch_size} rows a step)", unit="step")
        out = [self.spectrogram(*self.summed_rows(skeletons[b], masks[b], times=times,
                                                      arms=None if arms is None else arms[b])) for b in batches]
        return torch.cat(out) if out else torch.zeros(0, self.chain.n_doppler, self.chain.n_columns)

    def forward(self, skeleton: torch.Tensor, mask: torch.Tensor, weights: torch.Tensor | None = None, *,
                times: torch.Tensor | None = None, visibility: torch.Tensor | None = None) -> torch.Tensor:
        ctx = self.context(skeleton, mask, times=times, visibility=visibility)
        return self.render(self._profiles(ctx), weights, times=times)

