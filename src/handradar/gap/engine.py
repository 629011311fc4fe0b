"""Simulate many effect variants of one base simulator on the same rows, reusing what does not change.

A *variant* is the base simulator plus some effects at given values ({name: {param: value}}).
The gap diagnosis scores dozens of variants (every grid point of every candidate) on the same
rows, and most of the simulator's cost, the per-reflection-point range profiles, does not change
between them. Per batch of rows the base's context, reflection points and slot profiles are
computed once; then each variant takes the cheapest path that gives its signal:

- signal-stage effects only (noise): the base's summed signal goes through the variant's signal
  stage and the chain. Exact.
- scatterer-stage effects that only add reflection points (palm, forearm, multipath): base signal
  + the profiles of the added points. Exact (profiles add up).
  Appended points whose positions equal those of the previous variant and whose amplitudes differ
  by a per-point factor constant in time (multipath's scale and reflection coefficient, forearm's radius)
  reuse the stored per-point profiles scaled by that factor. Exact.
- scatterer-stage effects that only rescale points (occlusion, antenna_pattern): the base's slot
  profiles are re-weighted through Simulator.combine with the per-slot amplitude ratio as weights.
  Exact at the skeleton steps; between steps the simulator interpolates (amplitude x ratio)
  linearly and this path interpolates both linearly, a second-order difference (tests bound it).
- anything else (skeleton-stage effects, points that move): the variant's full simulation.

A variant may also come with its own factory (``factories``), whose generic settings differ from
the base's (step 0's grid, handradar.gap.fit.calibrate_settings). A setting of the signal's last
step (``coherence``) keeps the shortcuts above; one that changes the reflection points only
(``metacarpal_gain``) takes the scatterer-stage path, whose checks find the
re-weighting (the metacarpals' amplitude) or fall back to the full simulation (points that move);
any other (``rcs_exponent``, which the effects read from the context) takes the full simulation.

With coherence < 1 (Simulator.spectrogram) each path also gives the slots' own power: the base's
(signal path), the base's with slot 38 (where added points go) replaced, or the variant's slot
profiles' (re-weighted or full). Exact, computed only for variants that need it.

With a :class:`SpectrogramCache`, a variant's spectrogram of a row is simulated once per diagnosis:
engines whose variants are the same simulator (the same factory settings and effects, so the same
:meth:`Simulator.key`) share it. Cross-fitting's folds fit the same grid on complementary rows, so
each fold's out-of-fold predictions are mostly already there.

Reflection points with zero gain in a whole batch (an untracked hand) are skipped, and rows that
track the same hands are batched together, so one-hand rows cost about half.

Public API:

    RowSet(skeletons (N, T, 2, 21, 3), masks (N, T, 2), times (T,), visibility (N, T, 2, 19) | None)
        .take(idx) -> RowSet
    build: a handradar.sim.factory.SimFactory, build(effects {name: {param: value}}) -> Simulator
    SpectrogramCache()  .hits, .misses (row-variants taken from it / simulated into it)
    VariantEngine(build, base, rows, batch_size=8, cache=None)
        .spectrograms(variants, idx=None, progress=None, factories=None) -> (V, n, doppler, columns) float32
        .signals(variant, idx, grad=False) -> iterator of (batch idx, spectrograms) (differentiable)
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from handradar.provenance import config_hash
from handradar.radar.chain import profile_power
from handradar.sim.effects import REGISTRY
from handradar.sim.factory import SimFactory
from handradar.sim.scatterers import N_SLOTS, Scatterers
from handradar.sim.simulator import Simulator

Variant = Mapping[str, Mapping[str, float]]


@dataclass
class RowSet:
    """The skeleton windows a diagnosis simulates (dataset rows), float32 metres / bool / seconds."""

    skeletons: np.ndarray  # (N, T, 2, 21, 3)
    masks: np.ndarray  # (N, T, 2)
    times: np.ndarray  # (T,)
    visibility: np.ndarray | None = None  # (N, T, 2, 19) visible fraction (occlusion), or None

    def __len__(self) -> int:
        return int(self.skeletons.shape[0])

    def take(self, idx: np.ndarray) -> RowSet:
        idx = np.asarray(idx, dtype=np.int64)
        return RowSet(self.skeletons[idx], self.masks[idx], self.times,
                      None if self.visibility is None else self.visibility[idx])


def merge(base: Variant, added: Variant) -> dict[str, dict[str, float]]:
    """Effects of ``base`` plus ``added`` (an effect in both takes ``added``'s values)."""
    out = {k: dict(v) for k, v in base.items()}
    for k, v in added.items():
        out[k] = {**out.get(k, {}), **dict(v)}
    return out


# Simulator settings (Simulator.key()) that a variant's factory may change and still share the base's
# work: applied after the summed signal, or to the reflection points only (module doc)
SIGNAL_SETTINGS = frozenset({"coherence"})
SCATTERER_SETTINGS = frozenset({"metacarpal_gain"})


def settings_path(sim: Simulator, base: Simulator) -> str:
    """The cheapest path that the settings of ``sim`` (effects aside) allow from ``base``'s work:
    "signal", "scatterers" or "full" (module doc)."""
    k0, k1 = base.key(), sim.key()
    differ = {k for k in (set(k0) | set(k1)) - {"effects"} if k0.get(k) != k1.get(k)}
    if differ <= SIGNAL_SETTINGS:
        return "signal"
    return "scatterers" if differ <= SIGNAL_SETTINGS | SCATTERER_SETTINGS else "full"


def _same(a: torch.Tensor, b: torch.Tensor) -> bool:
    return a.shape == b.shape and bool(torch.equal(a, b))


def _amplitude(s: Scatterers) -> torch.Tensor:
    """Amplitude factor sqrt(RCS) x gain (B, T, K): what differs between points at the same positions."""
    return torch.sqrt(s.rcs_m2.clamp_min(0.0)) * s.gain


def _fingerprints(s: Scatterers) -> torch.Tensor:
    """One float64 number per point (K,) from all its fields: equal points give equal numbers."""
    g = torch.Generator().manual_seed(1234)
    b, t = s.gain.shape[:2]
    w = torch.rand(b, t, 8, generator=g, dtype=torch.float64) + 0.5
    parts = (s.tx.double() * w[..., None, :3]).sum(-1) + (s.rx.double() * w[..., None, 3:6]).sum(-1) \
        + s.rcs_m2.double() * w[..., 6:7] + s.gain.double() * w[..., 7:8]
    return parts.sum((0, 1)) + 1e3 * s.owner.double()


def extra_points(base: Scatterers, new: Scatterers) -> Scatterers | None:
    """The points of ``new`` that are not in ``base`` if every base point is in ``new`` unchanged
    (as multisets, in any order); None otherwise. Then new's signal = base's + the extra points'."""
    if new.n_points < base.n_points:
        return None
    f0, f1 = _fingerprints(base), _fingerprints(new)
    # equal points give equal fingerprints up to summation rounding (the layouts differ): match within
    # a relative 1e-9, then check the matched points exactly
    close = (f0[:, None] - f1[None, :]).abs() <= 1e-9 * f0.abs().clamp_min(1.0)[:, None]
    used = torch.zeros(new.n_points, dtype=torch.bool)
    match = []
    for i in range(base.n_points):
        js = torch.nonzero(close[i] & ~used).flatten()
        if js.numel() == 0:
            return None
        used[js[0]] = True
        match.append(int(js[0]))
    idx = torch.as_tensor(match, dtype=torch.long)
    fields = ((base.tx, new.tx), (base.rx, new.rx), (base.rcs_m2, new.rcs_m2), (base.gain, new.gain))
    if not all(torch.equal(a, b[:, :, idx]) for a, b in fields) or not torch.equal(base.owner, new.owner[idx]):
        return None  # a fingerprint collision: treat as changed
    rest = torch.ones(new.n_points, dtype=torch.bool)
    rest[idx] = False
    keep = torch.nonzero(rest).flatten()
    return Scatterers(new.tx[:, :, keep], new.rx[:, :, keep], new.rcs_m2[:, :, keep], new.gain[:, :, keep],
                      new.owner[keep])


def constant_ratio(new: torch.Tensor, ref: torch.Tensor, rtol: float = 1e-5) -> torch.Tensor | None:
    """Per (row, point) factor c with new = c ref at every step (B, K), or None if no such factor exists.

    new, ref: (B, T, K) amplitudes. Steps where ref is 0 need new = 0; points never non-zero get 0.
    """
    nz = ref != 0
    if bool((new[~nz] != 0).any()):
        return None
    ratio = torch.where(nz, new / torch.where(nz, ref, torch.ones_like(ref)), torch.zeros_like(ref))
    hi = torch.where(nz, ratio, torch.full_like(ratio, -torch.inf)).amax(1)
    lo = torch.where(nz, ratio, torch.full_like(ratio, torch.inf)).amin(1)
    seen = nz.any(1)
    hi, lo = torch.where(seen, hi, torch.zeros_like(hi)), torch.where(seen, lo, torch.zeros_like(lo))
    if bool(((hi - lo).abs() > rtol * torch.maximum(hi.abs(), lo.abs()).clamp_min(1e-30)).any()):
        return None
    return hi


def slot_weights(base: Scatterers, new: Scatterers, rtol: float = 1e-6) -> torch.Tensor | None:
    """Weights (B, T, 38) that turn the base's slot sums into ``new``'s, if ``new`` only rescales points.

    Every point of a bone slot must change by that slot's common factor, and the unweighted points
    (palm, forearm) must not change; otherwise None.
    """
    if new.n_points != base.n_points or not (_same(new.owner, base.owner) and _same(new.tx, base.tx)
                                             and _same(new.rx, base.rx) and _same(new.rcs_m2, base.rcs_m2)):
        return None
    g0, g1 = base.gain, new.gain
    nz = g0 != 0
    if bool((g1[~nz] != 0).any()):
        return None
    ratio = torch.where(nz, g1 / torch.where(nz, g0, torch.ones_like(g0)), torch.full_like(g0, torch.nan))
    # a step where a point reflects nothing (its hand untracked) takes the point's mean ratio over the
    # others, not 1: the weights are interpolated between steps, so a factor constant in time (the
    # metacarpals' amplitude) stays exact where a hand (un)tracks inside the window
    ratio = torch.where(nz, ratio, torch.nan_to_num(ratio.nanmean(1, keepdim=True), nan=1.0))
    b, t = ratio.shape[:2]
    owner = base.owner
    free = owner < 0
    if bool(free.any()) and not torch.allclose(ratio[..., free], torch.ones_like(ratio[..., free]), rtol=rtol, atol=0):
        return None
    w = torch.ones(b, t, N_SLOTS, dtype=ratio.dtype, device=ratio.device)
    bones = ~free
    first = torch.full((N_SLOTS,), -1, dtype=torch.long)
    for k in range(owner.shape[0]):  # K <= a few hundred: a Python loop over points is cheap here
        if not bool(bones[k]):
            continue
        s = int(owner[k])
        if first[s] < 0:
            first[s] = k
            w[..., s] = ratio[..., k]
        elif not torch.allclose(ratio[..., k], w[..., s], rtol=rtol, atol=1e-12):
            return None
    return w


def active(scat: Scatterers) -> tuple[Scatterers, torch.Tensor]:
    """The points with a non-zero gain somewhere in the batch (others reflect nothing) and their indices."""
    keep = torch.nonzero((scat.gain != 0).flatten(0, 1).any(0)).flatten()
    if keep.numel() == scat.n_points:
        return scat, keep
    return Scatterers(scat.tx[:, :, keep], scat.rx[:, :, keep], scat.rcs_m2[:, :, keep], scat.gain[:, :, keep],
                      scat.owner[keep]), keep


def profiles(sim: Simulator, scat: Scatterers, times: torch.Tensor) -> torch.Tensor:
    """The simulator's slot profiles of ``scat`` (B, 39, ...), skipping points that reflect nothing in the
    batch (an untracked hand: a batch of one-hand rows costs half). Same values as sim.profiles_of."""
    return sim.profiles_of(active(scat)[0], times)


def point_profiles(sim: Simulator, scat: Scatterers, times: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Profiles of each active point on its own (B, K_active, F, L, Ch, bins) and the points' indices
    (the slot layout holds 38 points at a time)."""
    scat, keep = active(scat)
    out = []
    for k0 in range(0, scat.n_points, N_SLOTS):
        k1 = min(scat.n_points, k0 + N_SLOTS)
        part = Scatterers(scat.tx[:, :, k0:k1], scat.rx[:, :, k0:k1], scat.rcs_m2[:, :, k0:k1],
                          scat.gain[:, :, k0:k1], torch.arange(k1 - k0, device=scat.tx.device))
        out.append(sim.profiles_of(part, times)[:, :k1 - k0])
    if not out:
        return torch.zeros(scat.tx.shape[0], 0, 1, dtype=torch.complex64), keep
    return torch.cat(out, 1), keep


class _Base:
    """One batch's base simulation: context, reflection points, slot profiles, summed signal, and
    (computed on first use) the slots' own power with slot 38 as is or with points added to it."""

    def __init__(self, ctx, scat: Scatterers, profiles: torch.Tensor, signal: torch.Tensor) -> None:
        self.ctx, self.scat, self.profiles, self.signal = ctx, scat, profiles, signal
        self._bones: torch.Tensor | None = None  # own power of the 38 bone slots
        self._free: torch.Tensor | None = None  # own power of slot 38 as the base has it

    def slot_power(self, sim: Simulator, extra: torch.Tensor | None = None) -> torch.Tensor:
        """The base slots' own power (B, doppler, columns), with ``extra`` (B, F, L, Ch, bins) added
        to slot 38 (the unweighted one) if given."""
        if self._bones is None:
            self._bones = sim.slot_power(self.profiles, unweighted=False)
            self._free = profile_power(self.free(), sim.chain)
        if extra is None:
            return self._bones + self._free
        return self._bones + profile_power(self.free() + extra, sim.chain)

    def free(self) -> torch.Tensor:
        """Slot 38's profiles (B, F, L, Ch, bins), complex."""
        p = self.profiles
        return p[:, N_SLOTS] if p.is_complex() else torch.view_as_complex(p[:, N_SLOTS].float().contiguous())


class _Appended:
    """Per-batch store of the last appended points' per-point profiles (for the constant-ratio reuse)."""

    def __init__(self) -> None:
        self.scat: Scatterers | None = None
        self.profiles: torch.Tensor | None = None
        self.keep: torch.Tensor | None = None

    def signal(self, sim: Simulator, app: Scatterers, times: torch.Tensor) -> torch.Tensor | None:
        """Summed profiles (B, F, L, Ch, bins) of the appended points (None: they reflect nothing)."""
        old = self.scat
        if old is not None and _same(app.owner, old.owner) and _same(app.tx, old.tx) and _same(app.rx, old.rx):
            c = constant_ratio(_amplitude(app), _amplitude(old))
            if c is not None:
                if self.profiles.shape[1] == 0:
                    return None
                c = c[:, self.keep].to(self.profiles.real.dtype).to(self.profiles.dtype)
                return torch.einsum("bk,bk...->b...", c, self.profiles)
        self.profiles, self.keep = point_profiles(sim, app, times)
        self.scat = app
        return self.profiles.sum(1) if self.profiles.shape[1] else None


class SpectrogramCache:
    """Spectrograms (doppler, columns) float32 by simulator (its :meth:`Simulator.key`) and row, for the
    engines of one diagnosis on one RowSet. A noise variant's draw depends on the batch it was simulated
    in; a cached row keeps the draw of the first simulation (every grid point of one fit still shares
    its rows' draws: they are simulated in the same pass)."""

    def __init__(self) -> None:
        self._specs: dict[str, dict[int, np.ndarray]] = {}
        self.hits = self.misses = 0

    @staticmethod
    def key(sim: Simulator) -> str:
        return config_hash(sim.key())

    def missing(self, key: str, rows: np.ndarray) -> np.ndarray:
        have = self._specs.get(key, {})
        return np.asarray([r for r in rows if int(r) not in have], dtype=np.int64)

    def put(self, key: str, rows: np.ndarray, specs: np.ndarray) -> None:
        have = self._specs.setdefault(key, {})
        for r, spec in zip(rows, specs):
            have[int(r)] = spec
        self.misses += len(rows)

    def get(self, key: str, rows: np.ndarray) -> np.ndarray:
        have = self._specs[key]
        return np.stack([have[int(r)] for r in rows])


class VariantEngine:
    """Spectrograms of variants of a base simulator on a RowSet (module doc: which path each takes)."""

    def __init__(self, build: SimFactory, base: Variant, rows: RowSet, *, batch_size: int = 8,
                 base_profiles: Callable[[np.ndarray], torch.Tensor] | None = None,
                 cache: SpectrogramCache | None = None) -> None:
        self.build, self.base, self.rows, self.batch_size = build, {k: dict(v) for k, v in base.items()}, rows, batch_size
        self.base_sim = build(self.base)
        self.base_profiles = base_profiles  # rows -> the base's slot profiles (e.g. from the slot-profile cache)
        self.cache = cache
        self.paths: Counter = Counter()  # (effects, path) -> batches: which shortcut each variant took

    def _batches(self, idx: np.ndarray) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """(positions in idx, rows) per batch; rows that track the same hands share batches, so that a
        batch of one-hand rows skips the other hand's reflection points."""
        hands = self.rows.masks[idx].any(axis=1)  # (n, 2) hand tracked somewhere in the window
        order = np.argsort(hands[:, 0] * 1 + hands[:, 1] * 2, kind="stable")
        for i0 in range(0, len(idx), self.batch_size):
            pos = order[i0:i0 + self.batch_size]
            yield pos, idx[pos]

    def _inputs(self, rows: np.ndarray) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor | None]:
        r = self.rows
        vis = None if r.visibility is None else torch.as_tensor(r.visibility[rows])
        return (torch.as_tensor(r.skeletons[rows]), torch.as_tensor(r.masks[rows]),
                torch.as_tensor(r.times, dtype=torch.float64), vis)

    def _path(self, sim: Simulator, added: Variant) -> str:
        stages = {REGISTRY[name].stage for name in added}
        by_settings = "signal" if sim is self.base_sim else settings_path(sim, self.base_sim)
        if "skeleton" in stages or by_settings == "full":
            return "full"
        return "scatterers" if "scatterers" in stages or by_settings == "scatterers" else "signal"

    def _signal(self, sim: Simulator, added: Variant, path: str, inputs, base: _Base, store: _Appended | None
                ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Summed signal of one variant on one batch (before its signal stage) and, when the variant's
        coherence is below 1, its slots' own power (else None); ``path``: its _path."""
        sk, m, t, vis = inputs
        ctx, s0, p0, sum0 = base.ctx, base.scat, base.profiles, base.signal
        own = sim.coherence < 1.0
        key = ",".join(sorted(added)) or "settings"
        if path == "signal":
            self.paths[key, "signal"] += 1
            return sum0, base.slot_power(sim) if own else None
        if path == "scatterers":
            s1 = sim.scatterers(ctx)
            app = extra_points(s0, s1) if s1.n_points > s0.n_points else None
            if app is not None:
                self.paths[key, "added"] += 1
                extra = store.signal(sim, app, ctx.times) if store is not None else \
                    profiles(sim, app, ctx.times).sum(1)
                if extra is None:
                    return sum0, base.slot_power(sim) if own else None
                extra = extra.to(sum0.dtype)
                # added points are unweighted: they join slot 38, the one slot whose own power changes
                power = base.slot_power(sim, extra) if own else None
                return sum0 + extra, power
            w = slot_weights(s0, s1)
            if w is not None:
                self.paths[key, "reweighted"] += 1
                return sim.combine(p0, w, times=t), sim.slot_power(p0, w, times=t) if own else None
            self.paths[key, "full"] += 1
            p1 = profiles(sim, s1, ctx.times)
            return sim.combine(p1), sim.slot_power(p1) if own else None
        self.paths[key, "full"] += 1
        ctx1 = sim.context(sk, m, times=t, visibility=vis)
        p1 = profiles(sim, sim.scatterers(ctx1), ctx1.times)
        return sim.combine(p1), sim.slot_power(p1) if own else None

    def _base(self, inputs, rows: np.ndarray) -> _Base:
        sk, m, t, vis = inputs
        ctx = self.base_sim.context(sk, m, times=t, visibility=vis)
        s0 = self.base_sim.scatterers(ctx)
        p0 = self.base_profiles(rows) if self.base_profiles is not None else profiles(self.base_sim, s0, ctx.times)
        return _Base(ctx, s0, p0, self.base_sim.combine(p0))

    @torch.no_grad()
    def spectrograms(self, variants: Sequence[Variant], idx: np.ndarray | None = None,
                     progress: Callable[[int], None] | None = None,
                     on_base: Callable[[np.ndarray, torch.Tensor], None] | None = None,
                     factories: Sequence[SimFactory] | None = None) -> np.ndarray:
        """Spectrograms (V, n, doppler, columns) of every variant (effects added to the base) on rows ``idx``.

        progress(n_rows) is called after each batch. Stochastic effects (noise) start from their
        seed in every call, so variants and repeated calls see the same draws (common random numbers).
        on_base(rows, base slot profiles) sees each batch's base profiles (per-bone decomposition).
        factories: each variant's factory (default: the engine's), e.g. other generic settings.
        With the engine's cache, only the rows a variant's simulator has not simulated yet are simulated.
        """
        idx = np.arange(len(self.rows)) if idx is None else np.asarray(idx, dtype=np.int64)
        if not len(idx):
            raise ValueError("no rows to simulate")
        if factories is not None and len(factories) != len(variants):
            raise ValueError(f"{len(factories)} factories for {len(variants)} variants")
        sims = [(self.build if factories is None else factories[j])(merge(self.base, v))
                for j, v in enumerate(variants)]
        if self.cache is None:
            return self._simulate(variants, sims, idx, progress, on_base)
        keys = [self.cache.key(sim) for sim in sims]
        if not keys:
            return self._simulate(variants, sims, idx, progress, on_base)
        missing = {j: m for j, k in enumerate(keys) if len(m := self.cache.missing(k, idx))}
        need = list(missing)
        todo = idx if on_base is not None else np.unique(np.concatenate(list(missing.values()) or [idx[:0]]))
        if len(todo):
            # a cached variant is not simulated again (its rows are cached); a needed one on every row of todo
            specs = self._simulate([variants[j] for j in need], [sims[j] for j in need], todo, progress, on_base)
            for j, spec in zip(need, specs):
                fresh = np.isin(todo, missing[j])
                self.cache.put(keys[j], todo[fresh], spec[fresh])
        if progress is not None and len(todo) < len(idx):
            progress(len(idx) - len(todo))
        self.cache.hits += sum(len(idx) for j in range(len(variants)) if j not in need)
        return np.stack([self.cache.get(k, idx) for k in keys])

    def _simulate(self, variants: Sequence[Variant], sims: Sequence[Simulator], idx: np.ndarray,
                  progress: Callable[[int], None] | None, on_base: Callable[[np.ndarray, torch.Tensor], None] | None
                  ) -> np.ndarray:
        """(V, n, doppler, columns): every variant's spectrograms on rows ``idx``, batch by batch."""
        paths = [self._path(sim, v) for sim, v in zip(sims, variants)]
        out: np.ndarray | None = None
        for pos, rows in self._batches(idx):
            inputs = self._inputs(rows)
            base = self._base(inputs, rows)
            if on_base is not None:
                on_base(rows, base.profiles)
            store = _Appended()
            for j, (v, sim, path) in enumerate(zip(variants, sims, paths)):
                spec = sim.spectrogram(*self._signal(sim, v, path, inputs, base, store)).float().numpy()
                if out is None:
                    out = np.zeros((len(variants), len(idx), *spec.shape[1:]), np.float32)
                out[j, pos] = spec
            if progress is not None:
                progress(len(rows))
        if out is None:  # no variant: the base alone was wanted (on_base)
            return np.zeros((0, len(idx)), np.float32)
        return out

    def signals(self, sim: Simulator, added: Variant, idx: np.ndarray) -> Iterator[tuple[np.ndarray, torch.Tensor]]:
        """(rows, spectrograms) per batch of one variant's simulator ``sim``, differentiable in its
        effect parameters (the base part is computed without gradient; appended points are not reused)."""
        idx = np.asarray(idx, dtype=np.int64)
        path = self._path(sim, added)
        for _, rows in self._batches(idx):
            inputs = self._inputs(rows)
            with torch.no_grad():
                base = self._base(inputs, rows)
            yield rows, sim.spectrogram(*self._signal(sim, added, path, inputs, base, None))
