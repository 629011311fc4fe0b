"""Per-reflection-point synthesis against the ADC path and closed-form Doppler lines."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import torch

from handradar.hand.retarget import standard_hand
from handradar.hand.skeleton import BONE_CHILD, BONE_NAMES, BONE_PARENT
from handradar.radar.chain import (
    power_to_unit,
    profile_power,
    range_profiles_from_adc,
    spectrogram_from_profiles,
    white_noise_power,
)
from handradar.radar.signal import beat_signal
from handradar.sim.cache import pack
from handradar.sim.interp import interpolate_time, upsample_to_chirps
from handradar.sim.profiles import combine_slots, scatterer_profiles, window_chirp_times
from handradar.sim.scatterers import (
    METACARPAL_SLOTS,
    N_SLOTS,
    Scatterers,
    radar_amplitude,
)
from handradar.sim.simulator import Simulator
from tests.sim.demo import window

AMP = dict(tx_power_w=0.0158, gain_tx_dbi=10.5, gain_rx_dbi=10.5)


def _steps(radar, chain, rate=100.0):
    n = int(round(chain.frames_per_window(radar) * radar.frame_period_s * rate))
    return np.arange(n) / rate


def _adc_profiles(radar, chain, tx_steps, rx_steps, amp_steps, times):
    """The ADC path: trajectory and amplitude interpolated to the chirp times, beat_signal, explicit FFT."""
    ct = window_chirp_times(radar, chain)  # (F, L, 1)
    flat = ct.reshape(-1)

    def lerp(x):
        return np.stack([np.interp(flat, times, x[:, i]) for i in range(x.shape[1])], -1)

    r = 0.5 * (np.linalg.norm(lerp(tx_steps), axis=-1) + np.linalg.norm(lerp(rx_steps), axis=-1))
    a = np.interp(flat, times, amp_steps)
    f = ct.shape[0]
    adc = beat_signal(radar, r.reshape(f, -1, 1, 1), a.reshape(f, -1, 1, 1))
    return range_profiles_from_adc(torch.as_tensor(adc), radar, chain)


@pytest.mark.parametrize("image", [False, True])
def test_point_scatterer_profiles_equal_the_adc_path(radar, short_chain, image):
    times = _steps(radar, short_chain)
    tx = np.stack([0.02 + 0.0 * times, 0.01 + 0.03 * times, 0.30 + 0.05 * np.sin(2 * np.pi * 1.3 * times)], -1)
    rx = tx * [1, 1, -1] - [0, 0, 0.1] if image else tx  # an image-like bistatic leg
    rcs = 1e-3 * (1 + 0.5 * np.sin(2 * np.pi * 2 * times))
    scat = Scatterers(torch.as_tensor(tx[None, :, None]), torch.as_tensor(rx[None, :, None]),
                      torch.as_tensor(rcs[None, :, None]), torch.ones(1, len(times), 1, dtype=torch.float64),
                      torch.tensor([5]))
    prof = scatterer_profiles(scat, torch.as_tensor(times), window_chirp_times(radar, short_chain), radar,
                              short_chain, **AMP)
    assert prof.shape[:2] == (1, 39) and prof.dtype == torch.complex128
    others = torch.cat([prof[0, :5], prof[0, 6:]])
    assert float(others.abs().max()) == 0.0  # the point's owner slot alone holds it
    amp = radar_amplitude(torch.as_tensor(rcs), torch.as_tensor(np.linalg.norm(tx, axis=-1)),
                          torch.as_tensor(np.linalg.norm(rx, axis=-1)), radar.wavelength_m, **AMP).numpy()
    adc = _adc_profiles(radar, short_chain, tx, rx, amp, times)
    err = (prof[0, 5].to(torch.complex64) - adc).abs().max() / adc.abs().max()
    assert err < 1e-4


def _bone_on_axis_window(times, z0, v_away, bone=8):
    """A standard hand translating along z whose bone ``bone`` has its midpoint on the z axis."""
    h = standard_hand()
    mid = 0.5 * (h[BONE_PARENT[bone]] + h[BONE_CHILD[bone]])
    pos = np.zeros((len(times), 2, 21, 3), np.float32)
    pos[:, 0] = h - mid + np.stack([0 * times, 0 * times, z0 + v_away * times], -1)[:, None, :]
    mask = np.zeros((len(times), 2), bool)
    mask[:, 0] = True
    return torch.as_tensor(pos[None]), torch.as_tensor(mask[None])


# velocities whose Doppler lands well inside a row (13.06 rows per m/s): the beat tone's phase across
# the fast-time window (range migration) moves the line by ~1 %, which decides a row only at x.5
@pytest.mark.parametrize("v_away", [-0.45, -0.15, 0.3, 0.62])
def test_single_cylinder_doppler_line_at_closed_form_row(radar, short_chain, v_away):
    times = _steps(radar, short_chain)
    sim = Simulator(radar, short_chain)
    pos, mask = _bone_on_axis_window(times, 0.40 if v_away < 0 else 0.18, v_away)
    w = torch.zeros(1, len(times), 38)
    w[..., 8] = 1.0  # one cylinder: the middle finger's proximal bone
    spec = sim(pos, mask, w)[0]
    v_toward = -v_away
    expected = round(2 * v_toward / radar.wavelength_m * short_chain.stft_len * radar.loop_period_s) + short_chain.stft_len // 2
    assert spec.argmax(0).tolist() == [expected] * short_chain.n_columns


def test_weights_are_upsampled_in_time_not_by_chirp_index(radar, short_chain):
    times = _steps(radar, short_chain)
    ct = window_chirp_times(radar, short_chain)
    ramp = torch.as_tensor(np.broadcast_to(times[None, :, None], (1, len(times), 38)).copy())
    up = upsample_to_chirps(ramp, torch.as_tensor(times), torch.as_tensor(ct))
    assert up.shape == (1, 38, *ct.shape)
    expected = np.clip(ct, times[0], times[-1])
    np.testing.assert_allclose(up[0, 3].numpy(), expected, atol=1e-12)
    # across a frame gap the value jumps by the idle time, as the clock does
    gap = float(up[0, 0, 1, 0, 0] - up[0, 0, 0, -1, 0])
    assert gap > 100 * radar.chirp_period_s
    x = torch.randn(2, len(times), 3, dtype=torch.float64)
    np.testing.assert_allclose(interpolate_time(x, torch.as_tensor(times), torch.as_tensor(times[3:7])).numpy(),
                               x[:, 3:7].numpy())


def test_combine_slots_matches_explicit_sum_and_float16_cache(radar, short_chain):
    times = _steps(radar, short_chain)
    pos, mask = window(times, hands=2)
    sim = Simulator(radar, short_chain)
    prof = sim.slot_profiles(torch.as_tensor(pos[None]), torch.as_tensor(mask[None]))
    w = 0.5 + torch.rand(1, len(times), 38)
    wc = sim.upsample(w)
    explicit = (prof[:, :38] * wc[..., None]).sum(1) + prof[:, 38]
    fast = combine_slots(prof, wc)
    torch.testing.assert_close(fast, explicit, rtol=1e-5, atol=1e-6 * float(explicit.abs().max()))
    packed, scale = pack(prof)
    assert packed.dtype == torch.float16 and packed.shape == (*prof.shape, 2)
    from_cache = sim.combine(packed, w, scale=scale)
    rel = (from_cache - explicit).abs().max() / explicit.abs().max()
    assert rel < 2e-3
    s_full = sim.spectrogram(explicit)
    s_cache = sim.spectrogram(from_cache)
    assert (s_full - s_cache).abs().max() < 0.01
    active = torch.zeros(38, dtype=torch.bool)
    active[:19] = True
    right_only = sim.slot_profiles(torch.as_tensor(pos[None]), torch.as_tensor(np.stack([mask[:, 0], 0 * mask[:, 1]], -1)[None]))
    torch.testing.assert_close(sim.combine(right_only, w, active=active), sim.combine(right_only, w))


def test_simulator_uses_the_shared_chain_and_is_batch_consistent(radar, short_chain):
    times = _steps(radar, short_chain)
    sk, mk = zip(*[window(times, hands=h, seed=s) for h, s in ((1, 0), (2, 1))])
    sk, mk = torch.as_tensor(np.stack(sk)), torch.as_tensor(np.stack(mk))
    sim = Simulator(radar, short_chain)
    spec = sim(sk, mk)
    assert spec.shape == (2, short_chain.stft_len, short_chain.n_columns)
    assert float(spec.min()) >= 0 and float(spec.max()) == 1.0
    prof = sim.slot_profiles(sk, mk)
    torch.testing.assert_close(spec, spectrogram_from_profiles(prof.sum(1), short_chain))
    torch.testing.assert_close(sim(sk[1:], mk[1:])[0], spec[1], atol=1e-5, rtol=0)
    # the untracked left hand of example 0 reflects nothing
    assert float(prof[0, 19:38].abs().max()) == 0.0 and float(prof[1, 19:38].abs().max()) > 0


def test_render_rows_is_render_of_the_slot_profiles(radar, short_chain):
    """Synthesis without RadarWeightNet renders window by window, caching nothing (at coherence 1 building no slot):
    the spectrograms and noise draws of render on the batch's slot profiles (coherence < 1: the slots' own power
    too)."""
    times = _steps(radar, short_chain)
    sk, mk = zip(*[window(times, hands=h, seed=s) for h, s in ((1, 0), (2, 1), (1, 2))])
    sk, mk = torch.as_tensor(np.stack(sk)), torch.as_tensor(np.stack(mk))
    for c in (1.0, 0.5):
        sim = Simulator(radar, short_chain, coherence=c, effects=["noise"],
                        effect_params={"noise": {"snr_db": 20.0, "draws": 1}})
        want = torch.cat([sim.render(sim.slot_profiles(sk[b], mk[b])) for b in (slice(0, 2), slice(2, 3))])
        sim.effect("noise").reset_rng()
        torch.testing.assert_close(sim.render_rows(sk, mk, batch_size=2), want, atol=1e-5, rtol=0)
    sim.effect("noise").reset_rng()
    whole = sim.render_rows(sk, mk, batch_size=3)  # the noise of a batch is drawn for its rows
    assert not torch.allclose(whole, want, atol=1e-3)  # other batches, other draws: the check has teeth


def test_silent_points_are_skipped_without_changing_the_profiles(radar, short_chain):
    """Without autograd, points of zero amplitude at every chirp (an untracked hand) are left out of
    the range response; the profiles are those of the full evaluation, which autograd still runs."""
    sim = Simulator(radar, short_chain)
    times = _steps(radar, short_chain)
    pos, mask = window(times, hands=1, seed=3)
    sk, mk = torch.as_tensor(pos[None]), torch.as_tensor(mask[None])
    with torch.no_grad():
        fast = sim.slot_profiles(sk, mk)
    full = sim.slot_profiles(sk.clone().requires_grad_(True), mk).detach()
    assert torch.equal(fast, full)
    assert float(fast[0, 19:].abs().max()) == 0.0


def test_profiles_of_silent_or_no_points_stay_differentiable(radar, short_chain):
    """A caller may backpropagate through points that all reflect nothing, or through none at all
    (the gap engine drops silent points first): the profiles still carry the graph (zero gradient)."""
    times = torch.as_tensor(_steps(radar, short_chain))
    ct = window_chirp_times(radar, short_chain)
    for k in (3, 0):
        tx = torch.full((1, len(times), k, 3), 0.3, dtype=torch.float64, requires_grad=True)
        scat = Scatterers(tx, tx, torch.full((1, len(times), k), 1e-3, dtype=torch.float64),
                          torch.zeros(1, len(times), k, dtype=torch.float64), torch.arange(k))
        prof = scatterer_profiles(scat, times, ct, radar, short_chain, **AMP)
        assert prof.requires_grad and float(prof.detach().abs().max()) == 0.0
        torch.view_as_real(prof).sum().backward()
        assert tx.grad is not None and float(tx.grad.abs().sum()) == 0.0


def test_chirp_times_of_the_window(radar, chain):
    ct = window_chirp_times(radar, chain)
    assert ct.shape == (16, 128, 1)
    assert math.isclose(ct[1, 0, 0] - ct[0, 0, 0], radar.frame_period_s)


def test_interpolation_paths_agree():
    """Sparse-matrix path (fixed times) and index path (differentiable times) give the same values."""
    from handradar.sim.interp import interp_weights, lerp

    t = torch.arange(20, dtype=torch.float64) / 100
    new = torch.linspace(-0.01, 0.2, 57, dtype=torch.float64)
    x = torch.randn(3, 20, 4, 2, dtype=torch.float64)
    lo, frac = interp_weights(t, new)
    fixed = lerp(x, lo, frac)
    moving = lerp(x, lo, frac.clone().requires_grad_(True))
    batched = lerp(x, lo.expand(3, -1), frac.expand(3, -1))
    torch.testing.assert_close(fixed, moving.detach())
    torch.testing.assert_close(fixed, batched)
    np.testing.assert_allclose(fixed[:, 0].numpy(), x[:, 0].numpy())  # clamped before the first step
    # samples moved to t_i - d: the value at t is x(t + d), whose derivative in d is dx/dt
    shift = torch.tensor(0.0031, dtype=torch.float64, requires_grad=True)
    y = interpolate_time(x, t - shift, torch.tensor([0.055], dtype=torch.float64))
    (g,) = torch.autograd.grad(y.sum(), shift)
    slope = (x[:, 6] - x[:, 5]).sum() / 0.01
    assert float(g) == pytest.approx(float(slope), rel=1e-9)


def test_interpolated_distance_is_the_norm_of_the_interpolated_point():
    """lerp_norm: |x(t)| of the linearly interpolated point, against the norm of lerp's (B, M, K, 3) result (shared
    and per-row times, clamped ends included), with its gradients in the positions and in the fractions."""
    from handradar.sim.interp import interp_weights, lerp, lerp_norm

    gen = torch.Generator().manual_seed(4)
    t = torch.arange(20, dtype=torch.float64) / 100
    new = torch.linspace(-0.01, 0.2, 57, dtype=torch.float64)
    x = (torch.randn(3, 20, 5, 3, generator=gen, dtype=torch.float64) * 0.05 + torch.tensor([0.0, 0.0, 0.3],
         dtype=torch.float64)).requires_grad_(True)
    lo, frac = interp_weights(t, new)
    frac = frac.clone().requires_grad_(True)
    want = lerp(x, lo, frac).norm(dim=-1)
    got = lerp_norm(x, lo, frac)
    torch.testing.assert_close(got, want, atol=1e-12, rtol=0)
    torch.testing.assert_close(lerp_norm(x, lo.expand(3, -1), frac.expand(3, -1)), want, atol=1e-12, rtol=0)
    w = torch.randn(want.shape, generator=gen, dtype=torch.float64)
    grads_want = torch.autograd.grad((want * w).sum(), (x, frac))
    grads_got = torch.autograd.grad((got * w).sum(), (x, frac))
    for g, h in zip(grads_got, grads_want):
        torch.testing.assert_close(g, h, atol=1e-10, rtol=0)
    # a point crossing the origin's neighbourhood between two steps: the distance dips below both ends
    line = torch.tensor([[[[-0.1, 0.01, 0.0]], [[0.1, 0.01, 0.0]]]], dtype=torch.float64)
    mid = lerp_norm(line, torch.tensor([0]), torch.tensor([0.5], dtype=torch.float64))
    assert float(mid) == pytest.approx(0.01, abs=1e-12)


@pytest.mark.slow
def test_compiled_weighted_sum_equals_eager(radar, short_chain):
    times = _steps(radar, short_chain)
    pos, mask = window(times, hands=2)
    sim = Simulator(radar, short_chain)
    fast = Simulator(radar, short_chain, compile_combine=True)
    prof = sim.slot_profiles(torch.as_tensor(pos[None]), torch.as_tensor(mask[None]))
    packed, scale = pack(prof)
    w = 0.5 + torch.rand(1, len(times), 38)
    torch.testing.assert_close(fast.combine(packed, w, scale=scale), sim.combine(packed, w, scale=scale), rtol=1e-5, atol=1e-9)


def test_tracking_gap_neither_sweeps_through_the_origin_nor_reflects(radar, short_chain):
    from handradar.sim.simulator import hold_untracked

    times = _steps(radar, short_chain)
    pos, mask = window(times, hands=1)
    mask[21:25, 0] = False  # inside frame 2 (0.2-0.25 s carries chirps)
    pos[21:25, 0] = 0.0
    held = hold_untracked(torch.as_tensor(pos[None]), torch.as_tensor(mask[None]))[0]
    torch.testing.assert_close(held[21:25, 0], torch.as_tensor(pos[20:21, 0]).expand(4, 21, 3))
    assert float(held[:, 1].abs().max()) == 0.0  # the never-tracked hand stays zero
    sim = Simulator(radar, short_chain)
    prof = sim.slot_profiles(torch.as_tensor(pos[None]), torch.as_tensor(mask[None]))
    # nothing reflects while the hand is untracked: the chirps strictly between steps 21 and 24
    ct = window_chirp_times(radar, short_chain).reshape(-1)
    inside = (ct > times[21] + 1e-9) & (ct < times[24] - 1e-9)
    flat = prof[0, :19].reshape(19, -1, prof.shape[-1])
    assert inside.any() and float(flat[:, torch.as_tensor(inside)].abs().max()) == 0.0


def test_rotating_bone_doppler_line_at_the_closed_form_row_of_its_midpoint(radar, short_chain):
    # the middle finger's proximal bone (8) turns at omega about its parent joint, broadside to the radar
    # (bone along x, line of sight along z) at the first STFT column's centre; the point at distance s
    # from the joint moves away at s omega cos(phi), so its midpoint (s = L / 2) draws one Doppler line
    bone, omega, z0 = 8, 20.0, 0.3
    times = _steps(radar, short_chain)
    h = standard_hand().astype(np.float64)
    p, c = h[BONE_PARENT[bone]], h[BONE_CHILD[bone]]
    e1 = (c - p) / np.linalg.norm(c - p)
    e2 = np.cross(e1, [0.0, 0.0, 1.0])
    e2 /= np.linalg.norm(e2)
    local = (h - p) @ np.stack([e1, e2, np.cross(e1, e2)]).T  # the bone along local x
    length = float(np.linalg.norm(c - p))
    t_c = float(window_chirp_times(radar, short_chain)[0, : short_chain.stft_len, 0].mean())
    phi = omega * (times - t_c)
    cos, sin = np.cos(phi)[:, None], np.sin(phi)[:, None]
    pos = np.zeros((len(times), 2, 21, 3))
    pos[:, 0, :, 0] = local[:, 0] * cos - local[:, 2] * sin
    pos[:, 0, :, 1] = local[:, 1]
    pos[:, 0, :, 2] = z0 + local[:, 0] * sin + local[:, 2] * cos
    mask = np.zeros((1, len(times), 2), bool)
    mask[..., 0] = True
    w = torch.zeros(1, len(times), 38)
    w[..., bone] = 1.0
    sim = Simulator(radar, short_chain)
    column = sim(torch.as_tensor(pos[None], dtype=torch.float32), torch.as_tensor(mask), w)[0, :, 0].numpy()
    rows_per_mps = short_chain.stft_len * radar.loop_period_s * 2 / radar.wavelength_m
    expected = [round(-0.5 * length * omega * rows_per_mps) + short_chain.stft_len // 2]
    peaks = [r for r in range(1, len(column) - 1) if column[r] >= max(column[r - 1], column[r + 1]) and column[r] > 0.8]
    assert peaks == expected


def window_times(radar, chain) -> np.ndarray:
    """Skeleton step times (s) at 100 Hz over one window of ``chain``."""
    return np.arange(int(round(chain.frames_per_window(radar) * radar.frame_period_s * 100))) / 100


def assert_setting_checked_and_keyed(radar, chain, name: str, bad: float, value: float) -> None:
    """Simulator setting ``name`` refuses ``bad``, is absent from key() at its default and keyed at ``value``."""
    with pytest.raises(ValueError, match=name):
        Simulator(radar, chain, **{name: bad})
    assert name not in Simulator(radar, chain).key()
    assert Simulator(radar, chain, **{name: value}).key()[name] == value


def test_metacarpal_gain_scales_the_metacarpals_only_and_is_validated_and_keyed(radar, short_chain):
    assert_setting_checked_and_keyed(radar, short_chain, "metacarpal_gain", 1.5, 0.25)
    t = window_times(radar, short_chain)
    pos, mask = window(t, hands=2, seed=3)
    sk, mk = torch.as_tensor(pos[None]), torch.as_tensor(mask[None])
    base, half = (Simulator(radar, short_chain, metacarpal_gain=g) for g in (1.0, 0.5))
    a, b = (s.scatterers(s.context(sk, mk)) for s in (base, half))
    meta = torch.isin(a.owner, torch.as_tensor(METACARPAL_SLOTS))
    assert [BONE_NAMES[int(k) % 19] for k in METACARPAL_SLOTS[:4]] == [f"{f}_metacarpal" for f in ("index", "middle", "ring", "pinky")]
    torch.testing.assert_close(b.gain[..., meta], 0.5 * a.gain[..., meta])
    torch.testing.assert_close(b.gain[..., ~meta], a.gain[..., ~meta])


def test_coherence_is_the_expected_power_over_unknown_slot_phases(radar, short_chain):
    """Simulator.render at coherence c = cos(a)^2 equals, exactly, the mean chain power over every
    draw of independent slot phases +-a (E[exp(i phi)] = cos a, so the cross terms keep cos(a)^2):
    c = 1 the coherent sum, c = 0 the sum of the slots' own power. Weights and the float16 cache's
    per-row scale enter the slots' own power as they enter the sum; c < 1 without the slots' power
    is refused, and the setting is validated and keyed."""
    assert_setting_checked_and_keyed(radar, short_chain, "coherence", 1.5, 0.5)
    t = window_times(radar, short_chain)
    pos, mask = window(t, hands=1, seed=5)
    sk, mk = torch.as_tensor(pos[None]).double(), torch.as_tensor(mask[None])
    full = Simulator(radar, short_chain).slot_profiles(sk, mk).to(torch.complex128)
    slots = [3, 7, 38]  # two bones and the unweighted slot: 2^3 phase draws
    prof = torch.zeros_like(full)
    prof[:, slots] = full[:, slots]
    weights = 0.5 + torch.rand(1, len(t), N_SLOTS, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    for a in (0.0, 0.7, np.pi / 2):
        sim = Simulator(radar, short_chain, coherence=float(np.cos(a) ** 2))
        w = sim.upsample(weights).repeat_interleave(radar.n_rx, dim=-1)[..., None]
        power = 0.0
        for signs in itertools.product((1.0, -1.0), repeat=len(slots)):
            s = sum(prof[:, k] * (w[:, k] if k < N_SLOTS else 1.0) * np.exp(1j * sg * a) for k, sg in zip(slots, signs))
            power = power + profile_power(s, short_chain) / 2 ** len(slots)
        torch.testing.assert_close(sim.render(prof, weights), power_to_unit(power, short_chain), atol=1e-6, rtol=0)
        scale = torch.tensor([3.0], dtype=torch.float64)
        torch.testing.assert_close(sim.render(prof, weights, scale=scale), sim.render(prof * 3.0, weights))
    with pytest.raises(ValueError, match="coherence < 1"):
        Simulator(radar, short_chain, coherence=0.5).spectrogram(Simulator(radar, short_chain).combine(prof))


def test_noise_under_coherence_below_one(radar, short_chain):
    """Below coherence 1 the noise's SNR is relative to the power shown (its level scaled by the shown
    total over |S|^2's), and a drawn noise is unrelated in phase to the slots: the power of a draw is
    c |S + n|^2 + (1 - c)(sum |s_k|^2 + |n|^2), never negative, where at c = 0 |S + n|^2 - |S|^2 +
    sum |s_k|^2 (the noise-free rule with the draw's cross term kept whole) goes negative."""
    t = window_times(radar, short_chain)
    pos, mask = window(t, hands=2, seed=5)
    sk, mk = torch.as_tensor(pos[None]).double(), torch.as_tensor(mask[None])
    prof = Simulator(radar, short_chain).slot_profiles(sk, mk).to(torch.complex128)
    for c in (0.0, 0.5):
        closed = Simulator(radar, short_chain, coherence=c, effects=["noise"],
                           effect_params={"noise": {"snr_db": 5.0, "draws": 0}})
        signal, slots = closed.combine(prof), closed.slot_power(prof)
        own = profile_power(signal, short_chain)
        shown = c * own + (1.0 - c) * slots
        ratio = float(shown.sum() / own.sum())
        level = closed.effect("noise").noise_power(signal) * ratio
        f, l, ch, bins = signal.shape[-4:]
        floor = white_noise_power(level.reshape(-1), short_chain, f, l, ch, bins)[..., None]
        torch.testing.assert_close(closed.render(prof), power_to_unit(shown + floor, short_chain), atol=1e-6, rtol=0)

        drawn = Simulator(radar, short_chain, coherence=c, effects=["noise"],
                          effect_params={"noise": {"snr_db": 30.0, "draws": 1}})
        noise = drawn.effect("noise")
        got = drawn.render(prof)
        noise.reset_rng()
        noisy = noise.apply_signal(signal, radar, short_chain, torch.tensor([ratio]))
        whole, alone = profile_power(noisy, short_chain), profile_power(noisy - signal, short_chain)
        if c == 0.0:  # the defect this rule avoids: one pixel suffices as a witness (at 10 dB this
            # draw has none under world/3's slot phases, at 30 dB it has)
            assert (whole - (own - slots)).min() < 0.0
        want = c * whole + (1.0 - c) * (slots + alone)
        assert want.min() >= 0.0 and torch.isfinite(got).all()
        torch.testing.assert_close(got, power_to_unit(want, short_chain), atol=1e-6, rtol=0)
