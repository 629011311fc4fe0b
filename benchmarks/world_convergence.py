"""Does the reference world converge with its tessellation? (``python -m benchmarks.world_convergence``)

The same recordings rendered at other facet layouts of the same surfaces, against the default layout:

- ``turn 0.5`` / ``turn 0.25``: every cylinder's facets turned by half / a quarter of a side and the
  palm's fan apex moved (``world.scene.facet_turn``). Half a side can land the physical-optics
  elements on the default's own grid (a facet cut into an even number of strips), a quarter never
  does, so both are reported;
- ``fine``: finger cylinders 12 sides x 4 rings (default 6 x 1), forearm 16 x 6 (8 x 3), palm
  subdivided twice (once).

Rows: the occluding gestures (grasp, finger_cross, double_hand_clap, hand_merge) of a few subjects
and angles. Printed per layout: median and largest 1 - SSIM over the rows, for the effect-free world
of the gap benchmark (every vocabulary effect off) and for the default world; spectrograms are
compared over the default layout's window (the chain picks the most energetic 16 frames, and a
near tie can flip that choice: how many rows flip is printed, with the median 1 - SSIM when each
layout picks its own window). Then each radar-side effect's signature (occlusion, multipath, palm:
the spectrogram with the effect minus without it, on the effect-free world) correlated with itself
at the other layouts, Pearson r per row. ``--figure PATH`` draws one recording at every layout.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context

import numpy as np
import torch

from benchmarks.bench_world import _configs
from handradar.metrics import per_example_ssim
from handradar.radar.chain import capture_spectrogram, spectrogram_from_profiles
from handradar.vocab import EFFECTS
from handradar.world.config import WorldConfig
from handradar.world.generate import RecordingSpec, simulate
from handradar.world.render import fast_profiles

OCCLUDING = ("grasp", "finger_cross", "double_hand_clap", "hand_merge")
LAYOUTS = {
    "default": {},
    "turn 0.5": {"facet_turn": 0.5},
    "turn 0.25": {"facet_turn": 0.25},
    "fine": {"finger_sides": 12, "finger_rings": 4, "forearm_sides": 16, "forearm_rings": 6, "palm_subdivisions": 2},
}
SIGNATURES = ("occlusion", "multipath", "palm")


def layout(world: WorldConfig, name: str) -> WorldConfig:
    return dataclasses.replace(world, scene=dataclasses.replace(world.scene, **LAYOUTS[name]))


def effect_free(world: WorldConfig, *on: str) -> WorldConfig:
    """The gap benchmark's effect-free world (every vocabulary effect off), with ``on`` switched on."""
    fx = world.effects
    for name in EFFECTS:
        fx = fx.with_(name, enabled=name in on)
    return dataclasses.replace(world, effects=fx)


def _init() -> None:
    torch.set_num_threads(1)


def _profiles(world: WorldConfig, radar, chain, spec: RecordingSpec) -> torch.Tensor:
    sim = simulate(world, radar, spec)
    return fast_profiles(sim.tracks, sim.radar, chain, sim.radar.n_frames, world.effects, sim.rng_noise,
                         sim.rng_quant, sim.noise_sigma)


def specs(n_rows: int) -> list[RecordingSpec]:
    """Occluding gestures, cycling through subjects and angles: n_rows recordings."""
    places = [(0, 0.0), (1, 30.0), (2, -30.0), (3, 0.0), (4, 30.0), (5, -30.0)]
    out = [RecordingSpec(g, s, a, 0) for s, a in places for g in OCCLUDING]
    return out[:n_rows]


def render_all(jobs: list[tuple], radar, chain, workers: int) -> list[torch.Tensor]:
    args = [(w, radar, chain, s) for w, s in jobs]
    if workers <= 1:
        _init()
        return [_profiles(*a) for a in args]
    with ProcessPoolExecutor(workers, mp_context=get_context("spawn"), initializer=_init) as pool:
        return list(pool.map(_profiles, *zip(*args), chunksize=1))


def spectrogram_at(profiles: torch.Tensor, radar, chain, start: int) -> torch.Tensor:
    fpw = chain.frames_per_window(radar)
    return spectrogram_from_profiles(profiles[start:start + fpw], chain)


def pearson(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a.ravel() - a.mean(), b.ravel() - b.mean()
    den = np.sqrt((a * a).sum() * (b * b).sum())
    return float((a * b).sum() / den) if den > 0 else float("nan")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rows", type=int, default=8, help="recordings (occluding gestures x subjects/angles)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--layouts", default=",".join(LAYOUTS), help="comma-separated subset of " + ", ".join(LAYOUTS))
    ap.add_argument("--no-signatures", action="store_true", help="skip the occlusion/multipath/palm signatures")
    ap.add_argument("--figure", default=None, help="also draw the first row at every layout to this PNG")
    ap.add_argument("--coherent-only", action="store_true",
                    help="physical optics alone: the skin texture (incoherent glossy/diffuse return) off")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    world, radar, chain = _configs()
    if args.coherent_only:
        world = dataclasses.replace(world, scene=dataclasses.replace(world.scene, skin_diffuse=0.0, skin_specular=0.0))
    cap = dataclasses.replace(radar, n_frames=world.capture_frames)
    rows = specs(args.rows)
    names = [n.strip() for n in args.layouts.split(",")]
    assert names[0] == "default", "the first layout is the reference"
    worlds = {"effect-free": effect_free(world), "default": world}
    if not args.no_signatures:
        worlds.update({f"+{e}": effect_free(world, e) for e in SIGNATURES})
    jobs = [(wname, lname, s) for wname in worlds for lname in names for s in rows]
    prof = render_all([(layout(worlds[w], lname), s) for w, lname, s in jobs], radar, chain, args.workers)
    by = dict(zip(jobs, prof))

    print(f"{'physical optics only, ' if args.coherent_only else ''}{len(rows)} rows ({', '.join(OCCLUDING)}), "
          f"{len(jobs)} renders, "
          f"{time.perf_counter() - t0:.0f} s on {args.workers} workers")
    starts = {}
    spec_of = {}
    for key, p in by.items():
        starts[key] = capture_spectrogram(p, cap, chain)[1]
    for (wname, lname, s), p in by.items():  # the effect-free world's default-layout window for every row
        spec_of[wname, lname, s] = spectrogram_at(p, cap, chain, starts[("effect-free", "default", s)])
    print("\n1 - SSIM against the default layout (common window; own windows: flips, median)")
    for wname in ("effect-free", "default"):
        for lname in names[1:]:
            ref = torch.stack([spec_of[wname, "default", s] for s in rows])
            oth = torch.stack([spec_of[wname, lname, s] for s in rows])
            d = 1 - per_example_ssim(ref, oth)
            own_ref = torch.stack([capture_spectrogram(by[wname, "default", s], cap, chain)[0] for s in rows])
            own_oth = torch.stack([capture_spectrogram(by[wname, lname, s], cap, chain)[0] for s in rows])
            d_own = 1 - per_example_ssim(own_ref, own_oth)
            flips = sum(starts[wname, "default", s] != starts[wname, lname, s] for s in rows)
            print(f"  {wname:11s} {lname:9s} median {np.median(d):.4f}  max {d.max():.4f} ({rows[int(d.argmax())].name})"
                  f"  | flips {flips}/{len(rows)}, median {np.median(d_own):.4f}")
    if not args.no_signatures:
        print("\neffect signatures (with - without, effect-free world): Pearson r with the default layout's")
        for e in SIGNATURES:
            sig = {lname: [(spec_of[f"+{e}", lname, s] - spec_of["effect-free", lname, s]).numpy() for s in rows]
                   for lname in names}
            size = np.median([np.abs(x).mean() for x in sig["default"]])
            for lname in names[1:]:
                r = np.array([pearson(a, b) for a, b in zip(sig["default"], sig[lname])])
                if np.isnan(r).all():  # the effect changes nothing in this world (e.g. bounces without texture)
                    print(f"  {e:10s} {lname:9s} no signature (mean |signature| {size:.4f})")
                    continue
                print(f"  {e:10s} {lname:9s} median r {np.nanmedian(r):.3f}  min {np.nanmin(r):.3f}   "
                      f"(mean |signature| {size:.4f})")
    if args.figure:
        _figure(args.figure, rows[0], [spec_of["default", lname, rows[0]] for lname in names], names)
        print(args.figure)
    return 0


def _figure(path: str, spec: RecordingSpec, maps: list[torch.Tensor], names: list[str]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(maps), figsize=(2.6 * len(maps), 3.2), sharey=True)
    for ax, m, name in zip(axes, maps, names):
        ax.imshow(m.numpy(), aspect="auto", origin="lower", cmap="viridis", vmin=0, vmax=1)
        ssim = 1 - per_example_ssim(maps[0][None], m[None])[0]
        ax.set_title(f"{name}\n1 - SSIM {ssim:.3f}", fontsize=9)
        ax.set_xlabel("column")
    axes[0].set_ylabel("Doppler row")
    fig.suptitle(f"{spec.name}, default world, at several facet layouts", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    raise SystemExit(main())
