"""Each effect: API contract, and that it changes the signal the way it claims (small checks)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from handradar.hand.retarget import standard_hand
from handradar.radar.chain import gate_bins, remove_static_clutter, stft_power, velocity_axis_m_s, window
from handradar.sim.effects import REGISTRY, STAGES, Effect, build_effects
from handradar.sim.effects.multipath import bounce_paths
from handradar.sim.effects.palm import palm_frame
from handradar.sim.profiles import scatterer_profiles
from handradar.sim.rcs import cos_angle, disc_rcs_m2
from handradar.sim.scatterers import Scatterers
from handradar.sim.simulator import Simulator
from handradar.vocab import EFFECTS as EFFECT_NAMES
from tests.sim.demo import window as hand_window


def steps(radar, chain, rate=100.0):
    n = int(round(chain.frames_per_window(radar) * radar.frame_period_s * rate))
    return np.arange(n) / rate


def batch(pos, mask):
    return torch.as_tensor(np.asarray(pos)[None]), torch.as_tensor(np.asarray(mask)[None])


def one_hand(times, joints_fn):
    pos = np.zeros((len(times), 2, 21, 3), np.float32)
    for i, t in enumerate(times):
        pos[i, 0] = joints_fn(t)
    mask = np.zeros((len(times), 2), bool)
    mask[:, 0] = True
    return pos, mask


def bin_power(profiles: torch.Tensor) -> torch.Tensor:
    """Mean power per gated range bin of (..., F, L, Ch, bins) profiles."""
    return (profiles.abs() ** 2).mean(dim=(-4, -3, -2)).flatten()


# ---- the API contract ----------------------------------------------------------------------------
def test_eight_registered_effects_follow_the_contract():
    assert set(EFFECT_NAMES) == {"occlusion", "palm", "forearm", "multipath", "antenna_pattern", "noise",
                                 "sync_offset", "tracking_jitter"}
    for name in EFFECT_NAMES:
        cls = REGISTRY[name]
        assert issubclass(cls, Effect) and cls.name == name and cls.stage in STAGES and cls.fit in ("grad", "grid")
        e = cls()
        assert e.values() == pytest.approx(cls.defaults())
        grid = cls.grid()
        assert 2 <= len(grid) <= 12 and all(set(g) == set(cls.params) for g in grid)
        for p in cls.params.values():
            assert p.low <= p.default <= p.high
        assert all(not p.requires_grad for p in e.parameters())  # frozen unless a fitter unfreezes them
        key = next(iter(cls.params))
        with pytest.raises(ValueError, match="outside its bounds"):
            e.set_values(**{key: cls.params[key].high + 1.0})
    with pytest.raises(ValueError, match="no parameter"):
        REGISTRY["noise"](snr=3)
    with pytest.raises(ValueError, match="unknown effect"):
        build_effects(["glare"])
    order = [e.name for e in build_effects(["noise", "occlusion", "sync_offset", "palm"])]
    assert order == ["sync_offset", "palm", "occlusion", "noise"]
    # parameters of unselected effects are allowed (a config may carry them all)
    assert [e.values() for e in build_effects(["noise"], {"noise": {"snr_db": 5.0}, "palm": {"radius_m": 0.03}})] == [{"snr_db": 5.0}]


def test_bounds_clamp_and_pass_gradients_at_the_bound():
    e = REGISTRY["occlusion"]()
    e.requires_grad_(True)
    with torch.no_grad():
        e.transmission.fill_(-0.5)
    v = e.value("transmission")
    assert float(v.detach()) == 0.0
    v.backward()
    assert float(e.transmission.grad) == 1.0  # straight through: a fitter can move it back inside
    e.clamp_()
    assert float(e.transmission.detach()) == 0.0


# ---- occlusion --------------------------------------------------------------------------------------
def test_occlusion_scales_amplitudes_by_visibility(radar, short_chain):
    times = steps(radar, short_chain)
    pos, mask = hand_window(times, hands=2)
    sk, mk = batch(pos, mask)
    vis = torch.ones(1, len(times), 2, 19)
    vis[:, :, 1] = 0.0  # the left hand fully hidden
    plain = Simulator(radar, short_chain).slot_profiles(sk, mk)
    occl = Simulator(radar, short_chain, effects=["occlusion"])
    hidden = occl.slot_profiles(sk, mk, visibility=vis)
    assert float(hidden[:, 19:38].abs().max()) == 0.0
    torch.testing.assert_close(hidden[:, :19], plain[:, :19])
    occl.effect("occlusion").set_values(transmission=0.25)
    part = occl.slot_profiles(sk, mk, visibility=vis)
    torch.testing.assert_close(part[:, 19:38], 0.5 * plain[:, 19:38])  # amplitude sqrt(0.25)
    occl.effect("occlusion").set_values(transmission=1.0)
    torch.testing.assert_close(occl(sk, mk, visibility=vis), Simulator(radar, short_chain)(sk, mk))


def test_occlusion_ray_casts_when_no_visibility_is_given(radar, short_chain):
    times = steps(radar, short_chain)[:6]
    right = standard_hand() + [0.0, -0.08, 0.25]
    left = standard_hand(hand="left") + [0.0, -0.08, 0.40]
    pos = np.broadcast_to(np.stack([right, left]), (len(times), 2, 21, 3)).astype(np.float32).copy()
    pos += (np.linspace(0, 0.01, len(times))[:, None, None, None] * np.array([0, 0, 1])).astype(np.float32)
    sk, mk = batch(pos, np.ones((len(times), 2), bool))
    sim = Simulator(radar, short_chain, effects=["occlusion"], skeleton_rate_hz=100.0)
    plain = Simulator(radar, short_chain)
    ratio_left = float(bin_power(sim.slot_profiles(sk, mk)[:, 19:38]).sum() / bin_power(plain.slot_profiles(sk, mk)[:, 19:38]).sum())
    ratio_right = float(bin_power(sim.slot_profiles(sk, mk)[:, :19]).sum() / bin_power(plain.slot_profiles(sk, mk)[:, :19]).sum())
    assert ratio_left < 0.4 < 0.8 < ratio_right  # the far hand lies in the near hand's shadow


# ---- palm ----------------------------------------------------------------------------------------
def test_palm_adds_a_disc_reflector_at_the_palm(radar, short_chain):
    times = steps(radar, short_chain)
    h = standard_hand()
    h = h - 0.5 * (h[0] + h[[5, 9, 13, 17]].mean(0))  # palm centre over the radar
    pos, mask = one_hand(times, lambda t: h + [0.0, 0.0, 0.30 - 0.3 * t])  # palm down, approaching
    sk, mk = batch(pos, mask)
    sim = Simulator(radar, short_chain, effects=["palm"])
    prof = sim.slot_profiles(sk, mk)
    ctx = sim.context(sk, mk)
    centre, normal = palm_frame(ctx.joints[0, :, 0])
    # the palm normal of a flat palm-down hand points along z: the disc faces the radar
    assert float((normal / normal.norm(dim=-1, keepdim=True))[:, 2].abs().min()) > 0.99
    peak_bin = int(bin_power(prof[:, 38]).argmax()) + gate_bins(radar, short_chain)[0]
    mean_range = float(centre.norm(dim=-1).mean())
    assert abs(peak_bin * radar.range_resolution_m - mean_range) <= radar.range_resolution_m
    # the unweighted slot is exactly one disc scatterer per tracked hand at the palm centre
    rcs = disc_rcs_m2(cos_angle(centre, normal), 0.02, radar.wavelength_m)
    disc = Scatterers(centre[None, :, None], centre[None, :, None], rcs[None, :, None], torch.ones_like(rcs)[None, :, None],
                      torch.tensor([-1]))
    alone = scatterer_profiles(disc, ctx.times, sim.chirp_times, radar, short_chain, tx_power_w=sim.tx_power_w,
                               gain_tx_dbi=sim.gain_tx_dbi, gain_rx_dbi=sim.gain_rx_dbi)[:, 38]
    torch.testing.assert_close(prof[:, 38], alone)
    # a disc facing the radar is a large reflector: it outshines all 19 finger bones together
    assert float(bin_power(prof[:, 38]).sum()) > 2 * float(bin_power(prof[:, :38].sum(1)).sum())
    sim.effect("palm").set_values(radius_m=0.005)
    small = float(bin_power(sim.slot_profiles(sk, mk)[:, 38]).sum()) / float(bin_power(prof[:, 38]).sum())
    assert small == pytest.approx((0.005 / 0.02) ** 4, rel=0.1)  # broadside disc RCS ~ a^4


# ---- forearm -------------------------------------------------------------------------------------
def _pointing_down(t: float) -> np.ndarray:
    """Hand pointing forward and down at 45 deg: its forearm runs back and up, away from the radar."""
    h = standard_hand()
    c = math.sqrt(0.5)
    rot = np.array([[1.0, 0, 0], [0, c, c], [0, -c, c]])  # +y -> (0, c, -c)
    return h @ rot.T + [0.0, -0.12, 0.42 + 0.02 * math.sin(2 * math.pi * 2 * t)]


def test_forearm_adds_reflectors_beyond_the_wrist(radar, short_chain):
    times = steps(radar, short_chain)
    sk, mk = batch(*one_hand(times, _pointing_down))
    b0 = gate_bins(radar, short_chain)[0]
    sim = Simulator(radar, short_chain, effects=["forearm"])
    extra = bin_power(sim.slot_profiles(sk, mk)[:, 38])
    wrist_range = float(np.linalg.norm(_pointing_down(0.0)[0]))
    bins = torch.arange(len(extra)) + b0
    mean_bin = float((extra * bins).sum() / extra.sum())
    assert mean_bin * radar.range_resolution_m > wrist_range + 0.03  # behind the wrist, seen from the radar
    far_short = int(torch.nonzero(extra > 1e-2 * extra.max()).max())
    sim.effect("forearm").set_values(length_m=0.28)
    extra_long = bin_power(sim.slot_profiles(sk, mk)[:, 38])
    far_long = int(torch.nonzero(extra_long > 1e-2 * extra_long.max()).max())
    assert far_long > far_short  # a longer forearm reaches farther bins
    assert float(bin_power(Simulator(radar, short_chain).slot_profiles(sk, mk)[:, 38]).sum()) == 0.0


def _swinging_rod(times: np.ndarray, omega: float, length: float = 0.26) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A hand on a forearm of ``length`` turning at ``omega`` rad/s about a fixed elbow in the x-z plane, along x at the
    window's middle with its outermost piece's midpoint (7/8 of it) on boresight at 0.45 m: (skeleton, mask, arm) of
    one window, the shoulder 0.3 m behind the elbow."""
    elbow = np.array([-0.875 * length, 0.0, 0.45])
    hand = standard_hand() @ np.array([[0.0, 1, 0], [-1, 0, 0], [0, 0, 1]]).T  # fingers along +x, continuing the rod
    hand = hand - hand[0] + elbow + [length, 0, 0]
    theta = omega * (times - times.mean())
    c, s = np.cos(theta), np.sin(theta)
    rot = np.zeros((len(times), 3, 3))
    rot[:, 0, 0], rot[:, 0, 2], rot[:, 1, 1], rot[:, 2, 0], rot[:, 2, 2] = c, -s, 1, s, c  # x -> (cos, 0, sin)
    pos, mask = one_hand(times, lambda t: hand)
    pos[:, 0] = np.einsum("tij,kj->tki", rot, hand - elbow) + elbow
    arm = np.zeros((len(times), 2, 2, 3), np.float32)
    arm[:, 0, 0], arm[:, 0, 1] = elbow, elbow + [0.0, 0.0, 0.3]
    return pos, mask, arm


def test_a_rod_swinging_about_one_end_has_doppler_from_zero_to_omega_l(radar, short_chain):
    """First principles: a rigid rod turning at omega about one end moves each of its points at omega s, s the distance
    from the pivot, so its Doppler runs from 0 to omega L. The forearm's points (n_segments at the pieces' midpoints
    s = (k + 1/2) L / n), their radial part that of omega x (p - pivot). Through the chain, the arm alone lights no
    Doppler bin beyond the outermost point's (within the Hamming window's main lobe, 2 bins) and none approaching (the
    upper arm, from the fixed elbow to the fixed shoulder, is still: clutter removal takes it), and its strongest bin
    is that of the piece seen nearest broadside: a cylinder's return is specular (handradar.sim.rcs)."""
    times = steps(radar, short_chain)
    v_axis = velocity_axis_m_s(radar, short_chain)
    bin_m_s = float(v_axis[1] - v_axis[0])
    for omega in (1.5, 3.0):
        pos, mask, arm = _swinging_rod(times, omega)
        sim = Simulator(radar, short_chain, effects=["forearm"])
        ctx = sim.context(*batch(pos, mask), times=torch.as_tensor(times), arm=torch.as_tensor(arm[None]))
        scat = sim.scatterers(ctx)
        fore = scat.tx[0, :, -16:-12].double().numpy()  # hand 0's forearm points (then hand 1's, then the upper arms)
        mid = len(times) // 2
        v = (fore[mid + 1] - fore[mid - 1]) / (times[mid + 1] - times[mid - 1])
        s_k = (1 - (np.arange(4) + 0.5) / 4) * 0.26  # from the wrist toward the pivot
        assert np.linalg.norm(v, axis=-1) == pytest.approx(omega * s_k, rel=1e-3)
        radial = (v * fore[mid]).sum(-1) / np.linalg.norm(fore[mid], axis=-1)
        turning = omega * np.cross([0.0, -1.0, 0.0], fore[mid] - arm[mid, 0, 0])  # omega x (p - pivot)
        assert radial == pytest.approx((turning * fore[mid]).sum(-1) / np.linalg.norm(fore[mid], axis=-1), rel=1e-3)
        prof = sim.slot_profiles(*batch(pos, mask), times=torch.as_tensor(times), arm=torch.as_tensor(arm[None]))
        prof[:, :38] = 0  # the arm's points alone (slot 38)
        col = sim.render(prof)[0, :, short_chain.n_columns // 2].numpy()
        lit = v_axis[col > 1 / 3]  # within 20 dB of the column's peak (the chain maps 30 dB to [0, 1])
        assert lit.min() >= -float(radial.max()) - 2 * bin_m_s and lit.max() <= bin_m_s  # receding: negative
        broadside = int(np.argmin(np.abs(fore[mid, :, 0]) / np.linalg.norm(fore[mid], axis=-1)))
        assert v_axis[int(np.argmax(col))] == pytest.approx(-radial[broadside], abs=bin_m_s)


# ---- multipath -----------------------------------------------------------------------------------
def test_multipath_bounce_paths_closed_form():
    """Path length |p| + d + |q| (directly or via the table image) and the two-scatterer radar equation."""
    f64 = dict(dtype=torch.float64)
    p, q = torch.tensor([0.0, 0.05, 0.30], **f64), torch.tensor([0.0, -0.06, 0.28], **f64)
    x = torch.tensor([1.0, 0.0, 0.0], **f64)  # both bones along x: broadside to every leg (all in the y-z plane)
    r, length, wl, h = torch.tensor(0.008, **f64), torch.tensor(0.04, **f64), 0.0039, 0.01
    cap = 2 * math.pi * 0.008 * 0.04**2 / wl
    for height, q_leg in ((None, q), (torch.tensor(h, **f64), q * torch.tensor([1.0, 1.0, -1.0], **f64) - torch.tensor([0, 0, 2 * h], **f64))):
        tx, rx, s_p, gain = bounce_paths(p, x, length, r, q, x, length, r, height, wl, 1.0)
        d = float((q_leg - p).norm())
        assert float(tx.norm() + rx.norm()) == pytest.approx(float(p.norm()) + d + float(q.norm()), rel=1e-12)
        torch.testing.assert_close(rx / rx.norm(), q / q.norm())  # arrives from q's direction
        amp = torch.sqrt(s_p) * gain / (tx.norm() * rx.norm())
        assert float(s_p) == pytest.approx(cap, rel=1e-9)
        expect = math.sqrt(cap * cap / (4 * math.pi)) / (float(p.norm()) * d * float(q.norm()))
        assert float(amp) == pytest.approx(expect, rel=1e-9)


def test_multipath_bounces_land_at_the_path_range_and_follow_the_bones(radar, short_chain):
    times = steps(radar, short_chain)
    sk, mk = batch(*hand_window(times, hands=2))
    plain = Simulator(radar, short_chain)
    sim = Simulator(radar, short_chain, effects=["multipath"],
                    effect_params={"multipath": {"height_m": 0.01, "reflection_coeff": 1.0, "scale": 1.0}})
    ctx = sim.context(sk.double(), mk, times=torch.as_tensor(times))
    scat = sim.scatterers(ctx)
    extra = scat.owner == -1
    assert int(extra.sum()) == 2 * sim.effect("multipath").n_paths
    # hand -> table -> hand paths run about twice the hand's range: their echoes lie beyond the hand
    b0 = gate_bins(radar, short_chain)[0]
    far = round(0.50 / radar.range_resolution_m) - b0
    mp, base = bin_power(sim.slot_profiles(sk, mk).sum(1)), bin_power(plain.slot_profiles(sk, mk).sum(1))
    assert float(mp[far:].sum()) > 100 * float(base[far:].sum())
    # an untracked hand bounces nothing; scale 0 is the plain simulator
    one = mk.clone()
    one[..., 1] = False
    gains = sim.scatterers(sim.context(sk.double(), one, times=torch.as_tensor(times))).gain[..., -sim.effect("multipath").n_paths:]
    assert float(gains.abs().max()) == 0.0
    sim.effect("multipath").set_values(scale=0.0)
    torch.testing.assert_close(sim(sk, mk), plain(sk, mk))


def test_multipath_is_differentiable_in_its_parameters(radar, short_chain):
    times = steps(radar, short_chain)[:8]
    sk, mk = batch(*hand_window(times, hands=2))
    sim = Simulator(radar, short_chain, effects=["multipath"]).double()
    eff = sim.effect("multipath").requires_grad_(True)
    ctx = sim.context(sk.double(), mk, times=torch.as_tensor(times))
    amp = sim.scatterers(ctx)
    loss = (torch.sqrt(amp.rcs_m2) * amp.gain / (amp.tx.norm(dim=-1) * amp.rx.norm(dim=-1))).sum() \
        + (amp.tx.norm(dim=-1) + amp.rx.norm(dim=-1)).sum()
    loss.backward()
    assert all(p.grad is not None and torch.isfinite(p.grad) and float(p.grad) != 0.0 for p in eff.parameters())


# ---- antenna pattern -----------------------------------------------------------------------------
def test_antenna_pattern_weights_off_boresight_hands_by_cos_q(radar, short_chain):
    times = steps(radar, short_chain)
    pos, mask = hand_window(times, hands=2)
    # move the left hand 50 deg off boresight (same range)
    c = pos[:, 1].mean(axis=(0, 1))
    rng_c = np.linalg.norm(c)
    target = rng_c * np.array([math.sin(math.radians(50)), 0.0, math.cos(math.radians(50))])
    pos[:, 1] += (target - c).astype(np.float32)
    sk, mk = batch(pos, mask)
    plain = Simulator(radar, short_chain).slot_profiles(sk, mk)
    q = 4.0
    sim = Simulator(radar, short_chain, effects=["antenna_pattern"], effect_params={"antenna_pattern": {"q": q}})
    pat = sim.slot_profiles(sk, mk)
    left = float(bin_power(pat[:, 19:38].sum(1)).sum() / bin_power(plain[:, 19:38].sum(1)).sum())
    right = float(bin_power(pat[:, :19].sum(1)).sum() / bin_power(plain[:, :19].sum(1)).sum())
    # power x G(theta)^2 = cos^(2q); the hands span some degrees, hence the tolerance
    assert left == pytest.approx(math.cos(math.radians(50)) ** (2 * q), rel=0.35)
    assert right > 0.8 and left < 0.05
    sim.effect("antenna_pattern").set_values(q=0.0)
    torch.testing.assert_close(sim.slot_profiles(sk, mk), plain)


# ---- noise ---------------------------------------------------------------------------------------
def test_noise_has_the_requested_snr_and_raises_the_floor(radar, short_chain):
    times = steps(radar, short_chain)
    sk, mk = batch(*hand_window(times))
    sim = Simulator(radar, short_chain, effects=["noise"], effect_params={"noise": {"snr_db": 10.0}})
    clean = sim.combine(sim.slot_profiles(sk, mk))
    noise_eff = sim.effect("noise")
    noisy = noise_eff.apply_signal(clean, radar, short_chain)
    dyn = remove_static_clutter(clean)
    p_sig = float((dyn.abs() ** 2).mean())
    p_noise = float(((noisy - clean).abs() ** 2).mean())
    assert 10 * math.log10(p_sig / p_noise) == pytest.approx(10.0, abs=0.3)
    # reproducible draws
    noise_eff.reset_rng()
    a = noise_eff.apply_signal(clean, radar, short_chain)
    noise_eff.reset_rng()
    torch.testing.assert_close(noise_eff.apply_signal(clean, radar, short_chain), a)
    # a lower SNR lifts the spectrogram's floor
    medians = []
    for snr in (40.0, 10.0, 0.0):
        noise_eff.set_values(snr_db=snr)
        noise_eff.reset_rng()
        medians.append(float(sim.spectrogram(clean).median()))
    assert medians[0] < medians[1] < medians[2]


def test_noise_draws_are_shared_by_generators_at_the_same_state(radar, short_chain):
    """Two noise effects seeded alike (two variants of one diagnosis pass) get the same draws, the
    second from the cache: bit-identical to drawing every ADC sample, and both generators move on alike."""
    from handradar.radar.chain import range_profiles_from_adc
    from handradar.sim.effects.noise import _DRAW_CACHE, unit_noise

    shape = (2, 3, radar.chirps_per_frame, radar.n_rx, radar.n_samples)
    g = torch.Generator().manual_seed(7)
    z = torch.complex(torch.randn(shape, generator=g), torch.randn(shape, generator=g)) / 2**0.5
    direct, direct_next = range_profiles_from_adc(z, radar, short_chain), torch.randn(5, generator=g)
    _DRAW_CACHE.clear()
    for _ in range(2):  # a miss, then a hit
        g = torch.Generator().manual_seed(7)
        drawn = unit_noise(g, shape, torch.float32, radar, short_chain)
        assert torch.equal(drawn, direct)
        assert torch.equal(torch.randn(5, generator=g), direct_next)  # the generator moved on as a draw does
    assert len(_DRAW_CACHE) == 1
    assert not torch.equal(unit_noise(torch.Generator().manual_seed(8), shape, torch.float32, radar, short_chain),
                           direct)  # another state, another draw


def test_noise_draws_average_to_the_expected_floor(radar, short_chain):
    times = steps(radar, short_chain)
    sk, mk = batch(*hand_window(times))

    def floor(draws: int, seed: int) -> torch.Tensor:
        sim = Simulator(radar, short_chain, effects=["noise"], effect_params={"noise": {"snr_db": 0.0}})
        sim.effect("noise").draws, sim.effect("noise").seed = draws, seed
        sim.effect("noise").reset_rng()
        with torch.no_grad():
            spec = sim.spectrogram(sim.combine(sim.slot_profiles(sk, mk)))[0]
        return spec[: short_chain.stft_len // 4]  # far from zero Doppler: noise only

    one, many = floor(1, 0), floor(16, 0)
    # the same level (the mean power of one draw is the expected power) ...
    assert float(many.mean()) == pytest.approx(float(one.mean()), abs=0.05)
    # ... without one draw's speckle: the floor of 16 averaged draws varies ~4x less pixel to pixel
    assert float(many.std()) < 0.5 * float(one.std())
    assert not torch.equal(floor(16, 1), many)  # still random draws (seeded)
    with pytest.raises(ValueError, match="draws"):
        REGISTRY["noise"](draws=-1)


@pytest.mark.parametrize("clutter", [True, False, "frame"])
def test_white_noise_power_is_the_monte_carlo_mean(radar, short_chain, clutter):
    """The closed form E[profile_power(noise)] = var n_ch n_bins (sum w^2 - |W(d)|^2 / N), N the chirps each clutter
    mean is over (the window's frames x loops, or a frame's loops), against
    the mean of 400 draws of the simulator's own noise (ADC samples through the range FFT): within
    5 sigma of the sampling error per row, and the notch at zero Doppler only with clutter removal."""
    from dataclasses import replace

    from handradar.radar.chain import (
        profile_power,
        range_profiles_from_adc,
        white_noise_power,
    )

    chain = replace(short_chain, clutter_removal=clutter)
    f = chain.frames_per_window(radar)
    gen = torch.Generator().manual_seed(0)
    shape = (400, f, radar.chirps_per_frame, radar.n_rx, radar.n_samples)
    z = torch.complex(torch.randn(shape, generator=gen, dtype=torch.float64),
                      torch.randn(shape, generator=gen, dtype=torch.float64)) / 2**0.5
    prof = range_profiles_from_adc(z, radar, chain)  # per-bin variance sum w_range^2
    power = profile_power(prof, chain)  # (400, doppler, columns)
    w2 = float((window(chain.range_window, radar.n_samples, dtype=torch.float64) ** 2).sum())
    _, frames, loops, ch, bins = prof.shape
    closed = white_noise_power(torch.tensor(w2, dtype=torch.float64), chain, frames, loops, ch, bins)
    rows = power.mean(dim=(0, 2))  # (doppler,)
    se = power.mean(dim=2).std(dim=0) / 400**0.5
    assert ((rows - closed).abs() < 5 * se).all()
    centre = chain.stft_len // 2
    notch = float(closed[centre] / closed[0])
    assert notch < 0.99 if clutter else notch == pytest.approx(1.0)


def test_noise_expected_power_is_the_limit_of_many_draws(radar, short_chain):
    """draws = 0 (closed form) against the power average of 256 draws: the same expected spectrogram
    to within the residual speckle of 256 draws, and closer to it than 4 draws are."""
    times = steps(radar, short_chain)
    sk, mk = batch(*hand_window(times))

    def spectrogram(draws: int) -> torch.Tensor:
        sim = Simulator(radar, short_chain, effects=["noise"], effect_params={"noise": {"snr_db": 0.0, "draws": draws}})
        with torch.no_grad():
            return sim.spectrogram(sim.combine(sim.slot_profiles(sk, mk)))[0]

    closed, many, few = spectrogram(0), spectrogram(256), spectrogram(4)
    assert float((closed - many).abs().mean()) < 0.01
    assert float((closed - many).abs().mean()) < 0.3 * float((closed - few).abs().mean())
    # deterministic: no generator is drawn from
    torch.testing.assert_close(spectrogram(0), closed, rtol=0, atol=0)


# ---- sync offset ---------------------------------------------------------------------------------
def test_sync_offset_moves_the_motion_onset(radar, short_chain):
    times = steps(radar, short_chain)
    t_on, v = 0.17, 0.4  # starts in frame 1's idle gap: columns 4.. move (two 25 ms columns per 100 ms frame)

    def pose(t):
        return standard_hand() + [0.0, -0.08, 0.35 - v * max(0.0, t - t_on)]

    sk, mk = batch(*one_hand(times, pose))
    row = round(2 * v / radar.wavelength_m * short_chain.stft_len * radar.loop_period_s) + short_chain.stft_len // 2

    def first_moving_column(sim):
        rows = sim(sk, mk)[0].argmax(0)
        return int(torch.nonzero(rows == row).min())

    assert first_moving_column(Simulator(radar, short_chain)) == 4
    lagging = Simulator(radar, short_chain, effects=["sync_offset"], effect_params={"sync_offset": {"offset_s": 0.1}})
    assert first_moving_column(lagging) == 2  # the skeleton lags by 0.1 s: the motion began one frame earlier
    # the same as feeding the skeleton with its times moved by -offset
    shifted = Simulator(radar, short_chain)(sk, mk, times=torch.as_tensor(times - 0.1))
    torch.testing.assert_close(lagging(sk, mk), shifted, atol=1e-4, rtol=0)  # the offset is a float32 parameter


# ---- tracking jitter -----------------------------------------------------------------------------
def test_tracking_jitter_smoothing_removes_jitter_doppler(radar, short_chain):
    times = steps(radar, short_chain)
    rng = np.random.default_rng(0)
    base = standard_hand() + [0.0, -0.08, 0.30]
    pos, mask = one_hand(times, lambda t: base)
    pos[:, 0] += rng.normal(scale=2e-4, size=pos[:, 0].shape).astype(np.float32)  # tracker jitter, 0.2 mm
    sk, mk = batch(pos, mask)
    offset = (torch.arange(short_chain.stft_len) - short_chain.stft_len // 2).abs()[:, None].float()

    def doppler_power(sim):
        power = stft_power(remove_static_clutter(sim.slot_profiles(sk, mk).sum(1)), short_chain)[0]
        return float(power.sum()), float((power * offset).sum() / power.sum())  # total, mean |row offset|

    raw_p, raw_spread = doppler_power(Simulator(radar, short_chain))
    smooth_p, smooth_spread = doppler_power(Simulator(radar, short_chain, effects=["tracking_jitter"],
                                                      effect_params={"tracking_jitter": {"sigma_s": 0.03}}))
    # a Gaussian of 3 samples passes 1 / (2 sqrt(pi) 3) ~ 0.09 of white jitter's power (more after the
    # window's mean removal and the interpolation to chirps)
    assert smooth_p < 0.2 * raw_p
    assert smooth_spread < 0.5 * raw_spread  # what is left sits near zero Doppler
    tiny = Simulator(radar, short_chain, effects=["tracking_jitter"], effect_params={"tracking_jitter": {"sigma_s": 0.0}})
    torch.testing.assert_close(tiny(sk, mk), Simulator(radar, short_chain)(sk, mk))


def test_all_effects_together_are_differentiable_in_their_parameters(radar, short_chain):
    times = steps(radar, short_chain)
    sk, mk = batch(*hand_window(times, hands=2))
    sim = Simulator(radar, short_chain, effects=list(EFFECT_NAMES))
    for e in sim.effects:
        e.requires_grad_(True)
    vis = torch.full((1, len(times), 2, 19), 0.5)
    sim(sk, mk, visibility=vis).mean().backward()
    for e in sim.effects:
        for name, p in e.named_parameters():
            assert p.grad is not None and torch.isfinite(p.grad), (e.name, name)
    grads = {e.name: float(next(e.parameters()).grad.abs()) for e in sim.effects if e.fit == "grad"}
    assert all(g > 0 for n, g in grads.items() if n not in ("multipath",)), grads
