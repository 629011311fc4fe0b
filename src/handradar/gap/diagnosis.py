"""The sim-to-real gap diagnosis: where the gap lies, which unmodelled effect causes it, how far it shrinks.

Given measured rows (spectrograms + skeleton windows) and a baseline simulator (``sim.effects``):

1. split the rows, seeded and stratified by gesture, into a calibration and an evaluation split;
   calibrate the baseline: the aspect exponent of its cylinder RCS (handradar.sim.rcs; 1 = the
   paper's formula) that fits the calibration split best (``rcs_exponents``), jointly with the
   metacarpals' amplitude (``metacarpal_gains``) and the share of the bones' cross terms kept in the
   power (``coherences``; Simulator.coherence), each off by default (the paper's cylinders and
   coherent sum; gap.report.GENERIC_SETTINGS). This generic
   calibration comes first so that candidates are scored on the gap it leaves: without it, any
   candidate that adds slow, broad returns (a palm disc, radar-table image paths) closes part of the generic
   "the cylinders are too specular" gap in every data set and wins where its effect is absent.
   Then the parameters of the effects already in the baseline (``sim.effects``) are fitted on the same
   rows, each on its grid (Effect.grid(), or ``grids``) given the others, in one coordinate pass in
   vocabulary order; the fitted values replace the defaults in the baseline before any candidate is
   scored (a baseline noise effect at its default SNR would otherwise leave a gap no candidate closes).
   The baseline, like every simulator here, takes a noise effect's expected power (closed form, or
   the mean of ``noise_draws`` draws): it too is compared through its expected spectrogram;
2. where: the signed mean residual (measured - simulated) over Doppler and time, SSIM by factor
   (gesture, angle, hands, occlusion, subject), and per reflection point from the per-bone
   decomposition (handradar.gap.where.BoneResiduals); all on the evaluation split;
3. which: every effect not in the baseline is a candidate; its parameters are fitted on the
   calibration split only (the documented grid, Effect.grid(), or ``grids``; then optional gradient
   steps for ``fit == "grad"``); its gap_closed on the evaluation split gets a paired-bootstrap 95 % CI,
   and the change it makes is correlated with the baseline residual (its signature), and its per-row gain
   with the factor its physics acts through (its specificity: handradar.gap.specificity);
   ``cause`` (:func:`decide`; its numbers: report key ``evidence``) has three outcomes:
   the leading candidate when its CI excludes 0, its gap_closed is at least ``min_gap_closed``,
   and the paired bootstrap of its lead over the runner-up excludes 0; "none" when the upper end
   of the leader's CI is below ``min_gap_closed`` (no candidate closes a relevant part of the gap);
   else "inconclusive", with an estimate of the recordings that would decide it
   (``recordings_needed``, from the CI half-widths scaled by 1/sqrt(rows));
4. how far: greedy forward selection from the leader, refitting every remaining candidate on
   calibration given those chosen, while one still closes a significant part of the remaining gap;
   then each chosen effect is refitted given the others; ``after`` is the combined result on the
   evaluation split;
5. optionally, how much a RadarWeightNet trained on the calibration split closes (handradar.gap.rwn).

Cross-fitting (``folds`` = k >= 2, in place of the single split; ``calibration_fraction`` unused): the
rows are cut, seeded and stratified by gesture, into k folds (:func:`cross_folds`; each holds every
gesture). For each fold, step 0 and every fit of steps 3 and 4 run on the other k - 1 folds (the
fitting subsets ``fit_rows``/``refine_rows`` drawn from them) and predict the fold's rows. Every row
is so scored out of fold, and every number computed from the scores uses all N rows: per-row SSIM,
the bootstrap CIs, the lead test and ``cause`` (the same rule, n_eval = N, and recordings_needed =
evaluation rows, since every recording is one), the greedy selection (each fold adds the chosen
effect at its own fitted values; which effect is chosen is decided on the out-of-fold scores),
``after``, and step 2 (from the out-of-fold baseline). The reported parameters (candidates'
``params``, ``after.params``, ``baseline.effects`` and ``calibration``, hence fitted_sim.yaml) come
from all N rows: step 0 fitted once more, each candidate's grid scores pooled over the folds
(handradar.gap.fit.pool_fits; refitted with ``refine_steps``); each fold's own are ``fold_params`` per candidate and
``baseline.calibration.folds``. Not cross-fitted: the RadarWeightNet readout (step 5) trains on the
other folds of one fold and is scored on that fold's rows only (``radarweightnet.fold``, ``evaluation_rows``):
fold 0, or the first fold with the 2 held-out rows its bootstrap needs; where no fold has them (one
gesture, no more recordings than folds) it is skipped, and the report's ``skipped`` says why.
Report convention: ``n_evaluation`` = N; ``n_calibration`` = the fewest rows any fold's fits saw
(N minus the largest fold). With folds = 1 nothing of this applies: the diagnosis is the single split
above, number for number. The default, folds = "auto" (:func:`resolve_folds`), cross-fits at every
size: in 3 folds below 60 rows (a user's folder of 36 recordings) and in 2 from there.

No code here reads meta.json ``truth``: the rows come from a dataset file, which has none.

Public API:

    DiagnosisConfig(...)        (fields below; conf/diagnose.yaml ``diagnose:``)
    diagnose(data: GapData, build: SimFactory, base: {effect: params}, cfg, *, cache_dir=None,
             progress=True) -> Diagnosis (report dict + the arrays the figures need)
    decide(effect, gap_closed, ci95, lead, lead_ci95, *, min_gap_closed, n_eval, calibration_fraction)
        -> {"cause", "decides", "evaluation_rows_needed", "recordings_needed"}   (step 3's verdict)
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from handradar.data.splits import stratified_partition
from handradar.gap.data import GapData
from handradar.gap.engine import SpectrogramCache, Variant, VariantEngine, merge
from handradar.gap.folds import AUTO, check_rows, cross_folds, fold_positions, readout_fold, readout_skip_reason, resolve_folds, stratified_subset
from handradar.gap.fit import (
    GridFit,
    calibrate_settings,
    effect_grid,
    fit_baseline_effects,
    generic_grid,
    grid_fit,
    in_vocabulary_order,
    pool_fits,
    refine,
)
from handradar.gap.report import FACTORS, FORMAT, GENERIC_SETTINGS
from handradar.gap.rwn import rwn_readout
from handradar.gap.specificity import pixel_specificity, row_factors, specificity
from handradar.gap.where import (
    BoneResiduals,
    by_factor,
    residual_profiles,
    signature_correlation,
    slot_power,
)
from handradar.metrics import (
    bootstrap_difference,
    bootstrap_gap_closed,
    gap_closed,
    per_example_mse,
    per_example_ssim,
)
from handradar.sim.cache import SlotProfileCache, cache_slot_profiles
from handradar.sim.effects import REGISTRY
from handradar.sim.factory import SimFactory
from handradar.sim.features import BoneFeatures, cached_bone_features
from handradar.sim.simulator import Simulator

log = logging.getLogger(__name__)


@dataclass
class DiagnosisConfig:
    """Settings of a diagnosis (``diagnose:`` in conf/diagnose.yaml)."""

    seed: int = 0  # fixes the split, the fitting subsets, the bootstrap and RadarWeightNet's training
    calibration_fraction: float = 0.5  # the single split's calibration share (folds = 1 only)
    candidates: list[str] | None = None  # None: every effect not in the baseline simulator
    rcs_exponents: list[float] | None = field(default_factory=lambda: [1.0, 0.75, 0.5, 0.25, 0.1, 0.0])
    # the baseline's cylinder RCS aspect exponents tried (None or [1.0]: the paper's RCS, uncalibrated)
    metacarpal_gains: list[float] | None = None  # ... and each metacarpal amplitude factor (None or [1.0]: not fitted)
    coherences: list[float] | None = None  # ... and each share of the bones' cross terms (None or [1.0]: not fitted)
    grids: dict[str, dict[str, list[float]]] | None = None  # {effect: {param: values}} replacing documented grids
    noise_draws: int = 4  # a noise effect's draws averaged in power (0: its expectation in closed form)
    fit_rows: int | None = None  # calibration rows the grid search scores (stratified subset); None: all
    refine_steps: int = 0  # gradient steps after the grid for effects with fit == "grad" (0: grid only)
    refine_rows: int = 8  # calibration rows of each gradient step
    refine_lr: float = 0.05  # Adam step as a fraction of each parameter's range
    n_boot: int = 2000
    min_gap_closed: float = 0.02  # smallest gap_closed worth naming a cause / adding an effect (conf/diagnose.yaml)
    greedy_max: int = 3  # most effects the forward selection adds
    batch_size: int = 8
    radarweightnet: bool = True
    rwn_epochs: int = 12
    rwn_lr: float = 3e-3
    rwn_batch_size: int = 8
    rwn_hidden: int = 64
    rwn_rows: int | None = None  # calibration rows RadarWeightNet trains on (None: all)
    n_examples: int = 4  # before/after examples in the markdown
    folds: int | str = 1  # 1: one split; k >= 2: cross-fitting in k folds; "auto": by the rows (resolve_folds;
    # conf/diagnose.yaml's default)

    @classmethod
    def from_mapping(cls, cfg: Mapping | None) -> DiagnosisConfig:
        cfg = dict(cfg or {})
        unknown = set(cfg) - set(cls.__dataclass_fields__)
        if unknown:
            raise ValueError(f"diagnose: unknown setting(s) {sorted(unknown)}; expected some of "
                             f"{sorted(cls.__dataclass_fields__)}")
        if cfg.get("candidates") is not None:
            cfg["candidates"] = [str(c) for c in cfg["candidates"]]
        for name, (_, _, top) in GENERIC_SETTINGS.items():
            if cfg.get(name) is not None:
                cfg[name] = [float(e) for e in cfg[name]]
                if not cfg[name] or not all(0.0 <= e <= top for e in cfg[name]):
                    raise ValueError(f"diagnose.{name}: values in [0, {top:g}] expected, found {cfg[name]}")
        if int(cfg.get("noise_draws", 1)) < 0:
            raise ValueError(f"diagnose.noise_draws must be >= 0 (0: the expectation in closed form), "
                             f"found {cfg['noise_draws']}")
        if cfg.get("grids") is not None:
            cfg["grids"] = {str(k): {str(p): [float(x) for x in v] for p, v in dict(g).items()}
                            for k, g in dict(cfg["grids"]).items()}
        return cls(**cfg)


Z95 = 1.96  # a 95 % CI read as mean +- Z95 * se (the recordings estimate of an inconclusive verdict)
# The estimate asks for 80 % power (the textbook sample size, n = (z_0.975 + z_0.8)^2 se_1^2 / margin^2):
# at the rows where the CI's half-width only reaches the margin, a new sample decides half the time
# (the default world's multipath asked for 391 recordings at 240 and was still undecided at 720).
Z_POWER = 0.8416
# An estimate beyond this many times the rows at hand is not given: its margin is under a seventh of the
# CI half-width, so the point estimates it extrapolates would move by more than the margin long before
# (a gap_closed 0.0004 under the threshold asked for 355915 recordings); the two are tied at any practical size.
MAX_ROWS_FACTOR = 100.0


def significant(gap_closed: float, ci95: Sequence[float], min_gap_closed: float) -> bool:
    """A candidate's gain is real (CI above 0) and relevant (at least ``min_gap_closed``)."""
    return ci95[0] > 0 and gap_closed >= min_gap_closed


def rows_to_decide(n_eval: int, ci95: Sequence[float], margin: float) -> float | None:
    """Evaluation rows at which a 95 % CI like ``ci95`` (from ``n_eval`` rows) clears the bound at
    ``margin`` from its mean with 80 % probability, if the mean is the truth: with se = (hi - lo) / (2 Z95)
    and se ~ 1/sqrt(rows), n_eval * ((Z95 + Z_POWER) se / margin)^2. At least
    n_eval + 1, since n_eval rows did not decide it (a skewed percentile CI can put the symmetric
    estimate below n_eval). None when the margin is <= 0 or a number is not finite (no number of
    rows decides it) or when the estimate exceeds MAX_ROWS_FACTOR * n_eval (no practical number)."""
    lo, hi = float(ci95[0]), float(ci95[1])
    if not (math.isfinite(margin) and margin > 0 and math.isfinite(lo) and math.isfinite(hi)):
        return None
    se = (hi - lo) / (2.0 * Z95)
    rows = n_eval * ((Z95 + Z_POWER) * se / margin) ** 2
    return None if rows > MAX_ROWS_FACTOR * n_eval else max(rows, n_eval + 1.0)


def decide(effect: str, gap_closed: float, ci95: Sequence[float], lead: float | None,
           lead_ci95: Sequence[float] | None, *, min_gap_closed: float, n_eval: int,
           calibration_fraction: float) -> dict:
    """The verdict on the leading candidate ``effect`` (gap_closed [ci95]; ``lead`` [lead_ci95]: its
    paired lead over the runner-up, None without one): ``cause`` = the effect, "none" or
    "inconclusive", and for "inconclusive" what must be shown (``decides``) and the rows that would
    show it with 80 % probability if the point estimates are the truth (``evaluation_rows_needed``;
    ``recordings_needed`` = calibration + evaluation at ``calibration_fraction``; None when no number
    of rows would)."""
    out: dict = {"cause": effect, "decides": None, "evaluation_rows_needed": None, "recordings_needed": None}
    ahead = lead_ci95 is None or lead_ci95[0] > 0
    relevant = gap_closed >= min_gap_closed
    if ci95[0] > 0 and relevant and ahead:
        return out
    if ci95[1] < min_gap_closed:
        out["cause"] = "none"
        return out
    out["cause"] = "inconclusive"
    if relevant:  # heading for naming the leader: each failing condition must be shown
        needs: dict[str, float | None] = {}
        if not ci95[0] > 0:
            needs[f"{effect}'s 95 % CI of gap_closed above 0"] = rows_to_decide(n_eval, ci95, gap_closed)
        if not ahead:
            needs[f"the 95 % CI of {effect}'s lead over the runner-up above 0"] = rows_to_decide(
                n_eval, lead_ci95, float("nan") if lead is None else lead)
    else:  # heading for "none": only the leader's upper bound matters, whatever the runner-up does
        needs = {f"{effect}'s upper 95 % bound of gap_closed below min_gap_closed {min_gap_closed:g} (cause none)":
                 rows_to_decide(n_eval, ci95, min_gap_closed - gap_closed)}
    undecidable = [what for what, n in needs.items() if n is None]
    if undecidable:
        out["decides"] = (f"{' and '.join(needs)}; no estimate: the margin of {' and '.join(undecidable)} "
                          f"is <= 0, not finite or under a seventh of its CI half-width (more than "
                          f"{MAX_ROWS_FACTOR:g}x the {n_eval} evaluation rows: tied at any practical size)")
        return out
    rows = max(needs.values())
    out["decides"] = " and ".join(needs)
    # rounded before the ceiling: float noise (240.00000000001 rows) must not ask for one more row
    out["evaluation_rows_needed"] = math.ceil(round(rows, 6))
    out["recordings_needed"] = math.ceil(round(rows / (1.0 - calibration_fraction), 6))
    return out


@dataclass
class Candidate:
    effect: str
    params: dict[str, float]  # fitted on the parameter-fitting rows (with folds: all rows)
    fit: GridFit  # that fit's grid scores
    ssim: np.ndarray  # per evaluation row (with folds: every row, scored out of fold)
    mse: np.ndarray
    gap_closed: float = 0.0
    ci95: tuple[float, float] = (0.0, 0.0)
    signature: float = 0.0
    spectrograms: np.ndarray | None = None  # evaluation rows
    fold_params: list[dict[str, float]] = field(default_factory=list)  # with folds: each fold's fit (scores its rows)
    specificity: dict | None = None  # does its gain come where its physics acts (handradar.gap.specificity)

    def significant(self, min_gap_closed: float) -> bool:
        return significant(self.gap_closed, self.ci95, min_gap_closed)

    def entry(self, min_gap_closed: float) -> dict:
        out = {"effect": self.effect, "params": {k: float(v) for k, v in self.params.items()},
               "ssim": float(self.ssim.mean()), "mse": float(self.mse.mean()), "gap_closed": float(self.gap_closed),
               "ci95": [float(self.ci95[0]), float(self.ci95[1])], "significant": self.significant(min_gap_closed),
               "signature_correlation": float(self.signature), "fit": self.fit.as_dict()}
        if self.specificity is not None:
            out["specificity"] = self.specificity
        if self.fold_params:
            out["fold_params"] = [{k: float(v) for k, v in p.items()} for p in self.fold_params]
        return out

    def on_rows(self, pos: np.ndarray, before_ssim: np.ndarray, params: dict[str, float]) -> Candidate:
        """This candidate on the evaluation positions ``pos`` only, at ``params`` (the fit that scored
        them); gap_closed against ``before_ssim`` (all evaluation rows), no CI."""
        return dataclasses.replace(self, params=params, ssim=self.ssim[pos], mse=self.mse[pos],
                                   gap_closed=float(gap_closed(before_ssim[pos], self.ssim[pos])),
                                   spectrograms=None, fold_params=[], specificity=None)


@dataclass
class Diagnosis:
    report: dict
    calibration: np.ndarray  # the rows the reported parameters are fitted on (with folds: all)
    evaluation: np.ndarray  # the rows every score is on (with folds: all, fold by fold)
    measured: np.ndarray  # evaluation rows
    baseline: np.ndarray  # evaluation rows, baseline simulator
    candidates: dict[str, np.ndarray] = field(default_factory=dict)  # effect -> evaluation spectrograms
    after: np.ndarray | None = None
    rwn: np.ndarray | None = None  # the RadarWeightNet readout's rows (rwn_rows)
    meta: dict[str, np.ndarray] = field(default_factory=dict)  # evaluation rows
    rwn_rows: np.ndarray | None = None  # positions in the evaluation arrays of the rows of ``rwn``


@dataclass
class Fold:
    """Parameters fitted on rows ``train`` (the grid on its stratified subset ``fit_idx``, gradient
    steps on ``refine_idx``) and predicted on rows ``test`` (none: the all-rows fit of cross-fitting,
    which gives the reported parameters). Step 0 sets ``build`` (the calibrated RCS exponent),
    ``base`` (the baseline's effects at their fitted values) and ``calibration`` (its record)."""

    train: np.ndarray
    test: np.ndarray
    fit_idx: np.ndarray
    refine_idx: np.ndarray
    build: SimFactory | None = None
    base: dict[str, dict[str, float]] = field(default_factory=dict)
    calibration: dict = field(default_factory=dict)
    profiles: Callable[[np.ndarray], torch.Tensor] | None = None  # rows -> cached baseline slot profiles


def _bar(total: int, desc: str, enabled: bool):
    return tqdm(total=total, desc=desc, unit="row", disable=not enabled, leave=False)


class _Runner:
    """Fitting candidates on some rows, predicting and scoring them on others (one diagnosis's data and settings)."""

    def __init__(self, data: GapData, cfg: DiagnosisConfig, progress: bool) -> None:
        self.data, self.cfg, self.progress = data, cfg, progress
        self.target = torch.as_tensor(data.measured)
        self.excluded: list[dict] = []  # candidates left out (non-finite simulations), for the report

    def scores(self, spec: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        m = self.target[idx]
        s = torch.as_tensor(spec)
        return per_example_ssim(m, s), per_example_mse(m, s)

    def fit(self, engine: VariantEngine, names: Sequence[str], fit_idx: np.ndarray, refine_idx: np.ndarray,
            step: str) -> dict[str, GridFit]:
        n_variants = sum(len(effect_grid(n, self.cfg.grids)) for n in names)
        with _bar(len(fit_idx), f"{step}: fit {len(names)} candidates ({n_variants} grid points)", self.progress) as bar:
            fits = grid_fit(engine, names, fit_idx, self.data.measured, progress=bar.update, grids=self.cfg.grids)
        if self.cfg.refine_steps > 0:
            grad = [n for n in names if REGISTRY[n].fit == "grad"]
            for name in tqdm(grad, desc=f"{step}: gradient refinement", disable=not self.progress, leave=False):
                f = fits[name]
                values = refine(engine, name, f.best, refine_idx, self.data.measured, steps=self.cfg.refine_steps,
                                lr=self.cfg.refine_lr)
                if values != f.best:  # keep the refined values only if they score better on the fit rows
                    spec = engine.spectrograms([{name: values}], fit_idx)[0]
                    score = float(self.scores(spec, fit_idx)[0].mean())
                    if score > f.best_score:
                        f.best, f.best_score, f.refined = values, score, True
        return fits

    def predict(self, engine: VariantEngine, fits: dict[str, GridFit], idx: np.ndarray, step: str,
                on_base=None) -> np.ndarray:
        """Spectrograms (1 + candidates, rows, doppler, columns) on rows ``idx``: the engine's base first,
        then the base plus each fitted candidate."""
        with _bar(len(idx), f"{step}: evaluate", self.progress) as bar:
            return engine.spectrograms([{}] + [{n: f.best} for n, f in fits.items()], idx, progress=bar.update,
                                       on_base=on_base)

    def assess(self, fold_fits: Sequence[dict[str, GridFit]], specs: np.ndarray, ev: np.ndarray,
               before_ssim: np.ndarray | None, step: str) -> tuple[np.ndarray, list[Candidate]]:
        """Candidates scored on the evaluation rows ``ev`` from their spectrograms ``specs`` there (base
        first, then each candidate of the fits), sorted by gap_closed against ``before_ssim`` (None:
        against that base). ``fold_fits``: one fit per fold, the last the reported one (module doc)."""
        *folds, reported = fold_fits
        base_spec = specs[0]
        before = self.scores(base_spec, ev)[0] if before_ssim is None else before_ssim
        res_map = (self.data.measured[ev] - base_spec).mean(0)
        out = []
        for name, spec in zip(reported, specs[1:]):
            fit = reported[name]
            if not np.all(np.isfinite(spec)):
                log.warning("%s: candidate %s at %s gives non-finite spectrograms; left out", step, name, fit.best)
                self.excluded.append({"effect": name, "params": fit.best, "step": step,
                                      "reason": "non-finite spectrograms"})
                continue
            ssim, mse = self.scores(spec, ev)
            boot = bootstrap_gap_closed(before, ssim, n_boot=self.cfg.n_boot, seed=self.cfg.seed)
            change = (spec - base_spec).mean(0)
            out.append(Candidate(name, fit.best, fit, ssim, mse, boot.estimate, boot.ci95,
                                 signature_correlation(res_map, change), spec, [f[name].best for f in folds]))
        out.sort(key=lambda c: c.gap_closed, reverse=True)
        return base_spec, out


def _evidence(before: np.ndarray, cands: list[Candidate], cfg: DiagnosisConfig) -> tuple[str, dict]:
    """The cause and the rule that gives it, with its numbers (report key ``evidence``)."""
    ev: dict = {"rule": "cause = the leading candidate when its 95 % CI of gap_closed excludes 0, its gap_closed "
                        f">= {cfg.min_gap_closed}, and the paired-bootstrap 95 % CI of its lead over the runner-up "
                        f"excludes 0; none when the upper end of the leader's CI is below {cfg.min_gap_closed}; "
                        "otherwise inconclusive, with the recordings that would decide it (CI half-widths scaled "
                        "by 1/sqrt(rows))",
                "leader": None, "runner_up": None, "leader_significant": False, "lead": None, "lead_ci95": None,
                "clearly_ahead": False, "decides": None, "evaluation_rows_needed": None, "recordings_needed": None}
    if not cands:
        return "none", ev
    lead = cands[0]
    ev.update(leader=lead.effect, leader_significant=lead.significant(cfg.min_gap_closed))
    if len(cands) > 1:
        run = cands[1]
        diff, ci = bootstrap_difference(before, lead.ssim, run.ssim, n_boot=cfg.n_boot, seed=cfg.seed)
        ev.update(runner_up=run.effect, lead=float(diff), lead_ci95=[float(ci[0]), float(ci[1])],
                  clearly_ahead=bool(ci[0] > 0))
    else:
        ev["clearly_ahead"] = True
    out = decide(lead.effect, lead.gap_closed, lead.ci95, ev["lead"], ev["lead_ci95"],
                 min_gap_closed=cfg.min_gap_closed, n_eval=len(before),
                 # cross-fitted, every recording is an evaluation row: recordings = evaluation rows
                 calibration_fraction=cfg.calibration_fraction if cfg.folds == 1 else 0.0)
    cause = out.pop("cause")
    ev.update(out)
    return cause, ev


class _Steps:
    """One diagnosis run as a sequence of named steps (:data:`STEPS`) sharing its state.

    ``folds`` (a list of :class:`Fold`): the last one gives the reported parameters (the single split,
    or with cross-fitting the all-rows fit after the k folds); ``scored``: the folds with held-out rows,
    whose predictions, in this order, make the evaluation arrays (``ev``: their rows, concatenated).
    Every fitting step runs in every fold, each given its own step-0 baseline and its own earlier fits.
    """

    def __init__(self, data: GapData, build: SimFactory, base: Variant, cfg: DiagnosisConfig, cache_dir: str | Path,
                 progress: bool) -> None:
        self.data, self.cfg, self.cache_dir, self.progress = data, cfg, cache_dir, progress
        self.base = {k: dict(v) for k, v in base.items()}
        self.names = [n for n in in_vocabulary_order(REGISTRY)
                      if n not in self.base and (cfg.candidates is None or n in cfg.candidates)]
        # every simulator of the diagnosis, the baseline's included, comes from this factory: a noise
        # effect in the baseline takes its expected power like a noise candidate, so the baseline is
        # compared through its expected spectrogram too (no single speckle pattern)
        self.build = build.replace(noise_draws=cfg.noise_draws)
        self.base_sim = self.build(self.base)
        self.features: BoneFeatures | None = None
        self.features_exponent = 1.0
        self.profiles: SlotProfileCache | None = None
        self.rwn_index: int | None = None  # the scored fold of the RadarWeightNet readout (None: not run)
        self.skipped: dict[str, str] = {}  # step -> why it did not run (the report's ``skipped``)
        self.runner = _Runner(data, cfg, progress)
        # every engine of the diagnosis shares it: the folds' fits and predictions overlap (engine doc)
        self.spectrograms = SpectrogramCache()
        self.report: dict = {}

    def bone_features(self, sim: Simulator) -> None:
        """Visibility (the occlusion effect) and RadarWeightNet's input, at ``sim``'s RCS exponent."""
        d = self.data
        self.features = cached_bone_features(d.rows.skeletons, d.rows.times, d.rows.masks, d.radar.wavelength_m,
                                             sim.hand, self.cache_dir, rcs_exponent=sim.rcs_exponent,
                                             progress=self.progress)
        d.rows.visibility = self.features.visible_fraction()
        self.features_exponent = sim.rcs_exponent

    def fold(self, train: np.ndarray, test: np.ndarray) -> Fold:
        labels, cfg = self.data.labels, self.cfg
        return Fold(train, test, stratified_subset(labels, train, cfg.fit_rows, cfg.seed + 1),
                    stratified_subset(labels, train, cfg.refine_rows, cfg.seed + 2))

    def engine(self, fold: Fold, current: Variant, cached: bool = False) -> VariantEngine:
        """Variants of ``current`` under the fold's calibrated factory (``cached``: from the fold's cached
        slot profiles, which are those of its step-0 baseline: only when ``current`` is that baseline)."""
        return VariantEngine(fold.build, current, self.data.rows, batch_size=self.cfg.batch_size,
                             base_profiles=fold.profiles if cached else None, cache=self.spectrograms)

    def fit_folds(self, currents: Sequence[Variant], names: Sequence[str], step: str,
                  cached: bool = False) -> list[dict[str, GridFit]]:
        """Candidates ``names`` fitted in every fold on its training rows, given its effects ``currents[j]``.
        Cross-fitted (grids only), the all-rows fit pools the folds' grid scores (handradar.gap.fit.pool_fits):
        each row's score under its fold's calibration, nothing simulated again."""
        fits = [self.runner.fit(self.engine(f, cur, cached), names, f.fit_idx, f.refine_idx, step)
                for f, cur in zip(self.scored, currents)]
        if len(self.folds) == len(self.scored):  # one split: its fit is the reported one
            return fits
        if self.cfg.refine_steps > 0:  # gradient steps leave the grid: refit on all rows
            reported = self.folds[-1]
            return [*fits, self.runner.fit(self.engine(reported, currents[-1]), names, reported.fit_idx,
                                           reported.refine_idx, step)]
        return [*fits, pool_fits(fits, [len(f.fit_idx) for f in self.scored])]

    def predict_folds(self, currents: Sequence[Variant], fold_fits: Sequence[dict[str, GridFit]], step: str,
                      on_base=None, cached: bool = False) -> np.ndarray:
        """Spectrograms (1 + candidates, evaluation rows, ...) of each fold's base ``currents[j]`` and its
        fitted candidates on its held-out rows, in evaluation-row order."""
        specs = [self.runner.predict(self.engine(f, cur, cached), fits, f.test, step, on_base)
                 for f, cur, fits in zip(self.folds, currents, fold_fits) if len(f.test)]
        return specs[0] if len(specs) == 1 else np.concatenate(specs, axis=1)

    def crossfit(self, currents: Sequence[Variant], names: Sequence[str], before_ssim: np.ndarray | None, step: str,
                 on_base=None, cached: bool = False) -> tuple[np.ndarray, list[Candidate]]:
        """Candidates fitted per fold (:meth:`fit_folds`), predicted on its held-out rows and scored on all
        evaluation rows (_Runner.assess); the base's evaluation spectrograms and the candidates."""
        fold_fits = self.fit_folds(currents, names, step, cached)
        specs = self.predict_folds(currents, fold_fits, step, on_base, cached)
        return self.runner.assess(fold_fits, specs, self.ev, before_ssim, step)

    @staticmethod
    def fold_values(c: Candidate) -> list[dict[str, float]]:
        """A candidate's fitted values per fold of ``folds`` (the cross-fitting folds', then the reported)."""
        return [*c.fold_params, c.params]

    # ---- the steps ---------------------------------------------------------------------------------
    def split(self) -> None:
        """The folds (module doc): one calibration/evaluation split, seeded and stratified by gesture; or
        k cross-fitting folds, each fitted on the others, and the all-rows fit."""
        cfg, labels = self.cfg, self.data.labels
        if cfg.folds == 1:
            f = cfg.calibration_fraction
            self.folds = [self.fold(*stratified_partition(labels, (f, 1.0 - f), cfg.seed, every_part=True))]
        else:
            every = np.arange(len(labels))
            parts = cross_folds(labels, cfg.folds, cfg.seed)
            self.folds = [self.fold(np.setdiff1d(every, p), p) for p in parts] + [self.fold(every, every[:0])]
        self.scored = [f for f in self.folds if len(f.test)]
        self.cal, self.ev = self.folds[-1].train, np.concatenate([f.test for f in self.scored])
        if len(self.ev) < 20:
            log.warning("only %d evaluation rows: bootstrap intervals over so few rows are too narrow to trust "
                        "(use 30 or more)", len(self.ev))

    def calibrate_fold(self, fold: Fold) -> None:
        """Step 0 on one fold's fitting rows: the generic settings (RCS exponent, metacarpal gain,
        coherence), then the baseline's own effects given them."""
        cfg, d = self.cfg, self.data
        build, calibration = self.build, {"rcs_exponent": 1.0, "grid": []}
        if len(self.generic_grid) > 1 or self.generic_grid[0] != {"rcs_exponent": 1.0}:
            with _bar(len(fold.fit_idx) * len(self.generic_grid), "step 0: calibrate the generic settings",
                      self.progress) as bar:
                best, scores = calibrate_settings(build, self.base, d.rows, fold.fit_idx, d.measured,
                                                  self.generic_grid, batch_size=cfg.batch_size, progress=bar.update,
                                                  cache=self.spectrograms)
            calibration = {**best, "grid": [{**point, "ssim": sc} for point, sc in zip(self.generic_grid, scores)]}
            build = build.replace(**best)
        with _bar(len(fold.fit_idx) * len(self.base), "step 0: fit the baseline's effects", self.progress) as bar:
            base, fits = fit_baseline_effects(build, self.base, d.rows, fold.fit_idx, d.measured, grids=cfg.grids,
                                              batch_size=cfg.batch_size, progress=bar.update, cache=self.spectrograms)
        calibration["effects"] = {k: dict(base[k]) for k in fits}
        calibration["effect_grids"] = {k: f.as_dict() for k, f in fits.items()}
        fold.build, fold.base, fold.calibration = build, base, calibration

    def calibrate(self) -> None:
        """Step 0 (module doc) before any candidate is scored, in every fold: the generic settings, then the
        parameters of the baseline's own effects given it; the fitted values replace the defaults in the
        baseline. The reported baseline is the last fold's (the parameter fit)."""
        if "occlusion" in self.base:  # the baseline simulated below then needs visibility
            self.bone_features(self.base_sim)
        self.generic_grid = generic_grid({name: getattr(self.cfg, name) for name in GENERIC_SETTINGS})
        for fold in self.folds:
            self.calibrate_fold(fold)
        reported = self.folds[-1]
        self.build, self.base, self.calibration = reported.build, reported.base, dict(reported.calibration)
        if len(self.folds) > 1:
            keys = [setting for setting, _, _ in GENERIC_SETTINGS.values()] + ["effects"]
            self.calibration["folds"] = [{k: f.calibration[k] for k in keys if k in f.calibration} for f in self.scored]
        self.base_sim = self.build(self.base)

    def cache(self) -> None:
        """Bone features and the readout fold's baseline slot profiles, where the later steps need them."""
        cfg, d = self.cfg, self.data
        held_out = [len(f.test) for f in self.scored]
        self.rwn_index = readout_fold(held_out) if cfg.radarweightnet else None  # the single split, or a fold
        if cfg.radarweightnet and self.rwn_index is None:
            self.skipped["radarweightnet"] = readout_skip_reason(held_out)
            log.warning("RadarWeightNet readout skipped: %s", self.skipped["radarweightnet"])
        readout = self.rwn_index is not None
        fold = self.scored[self.rwn_index or 0]
        sim = fold.build(fold.base)
        # RadarWeightNet reads the RCS at the calibrated exponent; visibility alone does not depend on it
        stale = self.features is None or (readout and self.features_exponent != sim.rcs_exponent)
        if ("occlusion" in self.names or readout) and stale:
            self.bone_features(sim)
        if readout:
            vis = d.rows.visibility if "occlusion" in self.base else None
            self.profiles = SlotProfileCache(cache_slot_profiles(
                sim, d.rows.skeletons, d.rows.masks, self.cache_dir, times=d.rows.times, visibility=vis,
                progress=self.progress))
            fold.profiles = self.profiles.profiles

    def which(self) -> None:
        """Every candidate fitted per fold and scored on its held-out rows; the cause."""
        cfg, d = self.cfg, self.data
        self.bones = BoneResiduals()
        powers: dict[int, torch.Tensor] = {}

        def keep_power(rows: np.ndarray, p0: torch.Tensor) -> None:  # per-bone power for "where", same pass
            pw = slot_power(p0, d.chain).float()
            for i, r in enumerate(rows):
                powers[int(r)] = pw[i]

        self.base_spec, self.cands = self.crossfit([f.base for f in self.folds], self.names, None, "step 1",
                                                   on_base=keep_power, cached=True)
        self.before_ssim, self.before_mse = self.runner.scores(self.base_spec, self.ev)
        self.assess_specificity()
        self.bones.add(torch.stack([powers[int(r)] for r in self.ev]), d.measured[self.ev] - self.base_spec,
                       self.base_spec)
        self.cause, self.evidence = _evidence(self.before_ssim, self.cands, cfg)

    def how_far(self) -> None:
        """Greedy forward selection from the leader while a candidate still closes a significant part;
        each fold adds the chosen effect at its own fitted values."""
        cfg = self.cfg
        chosen: list[Candidate] = []
        self.selection: list[dict] = [{"step": 1, "base": sorted(self.base), "candidates": [
            {"effect": c.effect, "gap_closed_of_remaining": c.gap_closed, "ci95": list(c.ci95)} for c in self.cands]}]
        pool = [c for c in self.cands if c.significant(cfg.min_gap_closed)]
        currents = [f.base for f in self.folds]
        ssim, mse, spec = self.before_ssim, self.before_mse, self.base_spec
        while pool and len(chosen) < cfg.greedy_max:
            best = pool[0]
            chosen.append(best)
            currents = [merge(cur, {best.effect: v}) for cur, v in zip(currents, self.fold_values(best))]
            ssim, mse, spec = best.ssim, best.mse, best.spectrograms
            # every candidate not chosen is refitted given those chosen, not only the ones significant
            # so far: a small effect (a sync offset) is masked while a larger one (jitter) is unmodelled
            excluded = {e["effect"] for e in self.runner.excluded}
            rest = [n for n in self.names if n not in currents[-1] and n not in excluded]
            if not rest or len(chosen) >= cfg.greedy_max:
                break
            step = f"step {len(chosen) + 1}"
            _, cands_k = self.crossfit(currents, rest, ssim, step)
            self.selection.append({"step": len(chosen) + 1, "base": sorted(currents[-1]), "candidates": [
                {"effect": c.effect, "params": c.params, "gap_closed_of_remaining": c.gap_closed, "ci95": list(c.ci95)}
                for c in cands_k]})
            pool = [c for c in cands_k if c.significant(cfg.min_gap_closed)]
        params = {c.effect: c.params for c in chosen}
        if len(chosen) > 1:  # each chosen effect refitted given the others (its first fit lacked the later ones)
            for name in list(params):
                without = [{k: v for k, v in cur.items() if k != name} for cur in currents]
                fold_fits = self.fit_folds(without, [name], "joint refit")
                for cur, fits in zip(currents, fold_fits):
                    cur[name] = fits[name].best
                params[name] = currents[-1][name]
            # the last refitted effect added to the others: every chosen effect at its refitted values
            specs = self.predict_folds(without, fold_fits, "joint refit")
            _, (joint,) = self.runner.assess(fold_fits, specs, self.ev, self.before_ssim, "joint refit")
            ssim, mse, spec = joint.ssim, joint.mse, joint.spectrograms
            self.selection.append({"step": "joint refit", "base": sorted(currents[-1]), "candidates": [],
                                   "params": dict(params)})
        self.after_spec = spec
        self.after = {"effects": [c.effect for c in chosen], "ssim": float(ssim.mean()), "mse": float(mse.mean()),
                      "gap_closed": float(gap_closed(self.before_ssim, ssim)), "params": params}

    def where(self) -> None:
        """Residual profiles over Doppler and time, SSIM by factor, per reflection point; the report."""
        cfg, d, ev = self.cfg, self.data, self.ev
        dop, tim = residual_profiles(d.measured[ev], self.base_spec)
        self.ev_meta = {k: v[ev] for k, v in d.meta.items()}
        where = {"doppler_profile": [float(v) for v in dop], "time_profile": [float(v) for v in tim],
                 "by_factor": by_factor(self.before_ssim, self.ev_meta, FACTORS), "reflection_points": self.bones.result()}
        # with folds, n_calibration is the fewest rows a fold's fits saw (module doc)
        self.report = {"format": FORMAT, "n_calibration": int(min(len(f.train) for f in self.scored)),
                       "n_evaluation": int(len(ev)),
                       "baseline": {"ssim": float(self.before_ssim.mean()), "mse": float(self.before_mse.mean()),
                                    "effects": {k: self.base_sim.effect(k).values() for k in self.base},
                                    "calibration": self.calibration},
                       "where": where,
                       "candidates": [c.entry(cfg.min_gap_closed) for c in self.cands],
                       "cause": self.cause,
                       "after": self.after,
                       "evidence": self.evidence,
                       "excluded": self.runner.excluded,
                       "skipped": self.skipped,
                       "selection": self.selection,
                       "settings": {"seed": cfg.seed, "calibration_fraction": cfg.calibration_fraction,
                                    "folds": cfg.folds, "fit_rows": int(len(self.folds[-1].fit_idx)),
                                    "refine_steps": cfg.refine_steps, "rcs_exponents": list(cfg.rcs_exponents or [1.0]),
                                    **{name: getattr(cfg, name) for name, (_, paper, _) in GENERIC_SETTINGS.items()
                                       if name != "rcs_exponents" and getattr(cfg, name) not in (None, [paper])},
                                    "grids": cfg.grids or {}, "n_boot": cfg.n_boot,
                                    "min_gap_closed": cfg.min_gap_closed}}

    def assess_specificity(self) -> None:
        """Each step-1 candidate's specificity evidence, where its physics names a factor (or pixels)."""
        factors = row_factors(self.data.rows.take(self.ev))
        measured, boot = self.data.measured[self.ev], {"n_boot": self.cfg.n_boot, "seed": self.cfg.seed}
        for c in self.cands:
            c.specificity = (specificity(c.effect, c.ssim - self.before_ssim, factors, **boot)
                             or pixel_specificity(c.effect, measured, self.base_spec, c.spectrograms, **boot))

    def readout(self) -> None:
        """How much a RadarWeightNet trained on the readout fold's training rows closes on its held-out
        rows (handradar.gap.rwn); with folds, the first fold with READOUT_MIN_ROWS held-out rows
        (:func:`readout_fold`), against the candidates at that fold's fits. Skipped (the report's
        ``skipped``) where no fold has them."""
        cfg, k = self.cfg, self.rwn_index
        self.rwn_spec = self.rwn_rows = None
        if k is None:
            return
        f = self.scored[k]
        pos = fold_positions([len(s.test) for s in self.scored], k)
        cands = self.cands if len(self.folds) == 1 else [
            c.on_rows(pos, self.before_ssim, c.fold_params[k]) for c in self.cands]
        train_idx = stratified_subset(self.data.labels, f.train, cfg.rwn_rows, cfg.seed + 3)
        self.report["radarweightnet"], self.rwn_spec = rwn_readout(
            self.data, f.build, f.base, self.features, self.profiles, train_idx, f.test, self.before_ssim[pos],
            cands, cfg, progress=self.progress)
        if len(self.folds) > 1:
            self.report["radarweightnet"].update(fold=k, evaluation_rows=int(len(f.test)))
        self.rwn_rows = pos


# The diagnosis, in order; each is a method of _Steps, and its wall time is reported under its name.
STEPS = ("split", "calibrate", "cache", "which", "how_far", "where", "readout")


def diagnose(data: GapData, build: SimFactory, base: Variant, cfg: DiagnosisConfig | Mapping | None = None, *,
             cache_dir: str | Path | None = None, progress: bool = True) -> Diagnosis:
    """Run the diagnosis (module doc, :data:`STEPS`) on ``data`` with the baseline simulator ``build(base)``."""
    cfg = cfg if isinstance(cfg, DiagnosisConfig) else DiagnosisConfig.from_mapping(cfg)
    unknown = [n for n in (cfg.candidates or []) if n not in REGISTRY]
    if unknown:
        raise ValueError(f"unknown candidate effect(s) {unknown}; expected some of {sorted(REGISTRY)}")
    if not 0.0 < cfg.calibration_fraction < 1.0:
        raise ValueError(f"calibration_fraction must be in (0, 1), found {cfg.calibration_fraction}")
    check_rows(data.labels, cfg.folds, cfg.calibration_fraction, cfg.seed)  # before minutes of fitting
    folds = resolve_folds(cfg.folds, data.labels)
    if cfg.folds == AUTO:
        log.info("diagnose.folds=auto: %d rows -> %s", len(data.labels),
                 "one calibration/evaluation split" if folds == 1 else f"cross-fitting in {folds} folds")
    cfg = dataclasses.replace(cfg, folds=folds)  # every step below sees the resolved count
    with contextlib.ExitStack() as stack:
        if cache_dir is None and cfg.radarweightnet:
            cache_dir = stack.enter_context(tempfile.TemporaryDirectory(prefix="handradar-gap-"))
        run = _Steps(data, build, base, cfg, cache_dir, progress)
        timings: dict[str, float] = {}
        for name in STEPS:
            t0 = time.perf_counter()
            getattr(run, name)()
            timings[name] = round(time.perf_counter() - t0, 2)
            log.info("%s: %.1f s", name, timings[name])
        run.report["timings_s"] = timings
        log.info("row-variants simulated: %d; taken from the diagnosis's cache: %d", run.spectrograms.misses,
                 run.spectrograms.hits)
        return Diagnosis(run.report, run.cal, run.ev, data.measured[run.ev], run.base_spec,
                         {c.effect: c.spectrograms for c in run.cands}, run.after_spec, run.rwn_spec, run.ev_meta,
                         run.rwn_rows)
