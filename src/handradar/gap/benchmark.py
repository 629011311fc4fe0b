"""Validation of the gap diagnosis on data whose effect was withheld (``+experiment=gap_benchmark``).

Cases (``benchmark.cases``): for each of the eight effects, reference-world data with that effect
on and the other vocabulary effects off, diagnosed by the simulator without it (``sim.effects``
of the preset, normally none); ``nothing``: a world with no vocabulary effect (the right answer
is "none"); ``iq_imbalance``: a world whose only effect is outside the vocabulary ("none" again).
An "inconclusive" answer is wrong in every case: a withheld effect is there to be named, a control
has none to be shown.
The world's other settings are shared by every case: the ``world`` config group (``world=heldout``
runs the benchmark on another world's physics), then the size's settings (``benchmark.sizes`` at
``benchmark.size``: 240 or 36 recordings per case), then ``benchmark.world`` (keys of
handradar.world.WorldConfig) on top (:func:`benchmark_world`); ``benchmark.strengths``
({effect: {param: value}}) sets the withheld effect's own parameters in its case (an effect must
change the radar data to cause a gap at all: see the radar signature column). Each case's dataset is built once by ``benchmark.builder`` (cached by config hash)
and diagnosed by exactly the code diagnose.py runs on recordings; its report is kept in the run
folder and, keyed by the case and every setting, in ``benchmark.state_dir`` so that a stopped
benchmark resumes.

Scoring is the only place that knows the truth, and it takes it from the world configuration this
module generated (the case), never from the data the diagnosis sees.

``benchmark.folders`` (a manifest, :class:`FolderCases`) judges folders of recordings instead of worlds:
held-back folders from other sources, each with its known answer. They are ingested and diagnosed as
``diagnose.py data.root=DIR`` does, the truth comes from the manifest, and there is no truth side.

Outputs, all in the run folder (never into docs/): ``figures/gap_confusion.png`` (withheld effect x
attributed cause), ``gap_benchmark.md`` (the top-1 attribution and gap_closed per case),
``benchmark.json`` (every figure) and ``record.json``, the compact record
(handradar.gap.records) that ``make gap-report`` renders; ``benchmark.record_dir`` also keeps the
record there as ``<world>_<size>.json`` (results/gap_benchmark holds the published ones).

Public API:

    Case(name, world_effects_on, truth);  cases(names) -> list[Case]
    case_world(world_overrides, case, strengths=None) -> dict   (world config of one case)
    spectrograms(path) -> torch.Tensor;  window_starts(path) -> np.ndarray   (a dataset's rows; window starts, s)
    radar_signature(case_path, clean_path) -> dict    (truth side: how much the effect changes the radar data)
    effect_reference(measured, clean, baseline) -> dict   (truth side: the world's change added to the
                                                       simulator's baseline spectrograms)
    change_correlation(world_change, candidate_change) -> float   (Pearson r over every pixel)
    benchmark_world(cfg) -> dict                      (the world settings every case shares)
    BenchmarkWorlds.from_config(cfg)     (a preset's worlds: .config(case), .dataset(case, window_starts_s=None),
                                          .clean(window_starts_s=None), .radar, .chain)
    truth_side(worlds, case_path, clean_path, ...) -> dict   (both, over the case's windows)
    truth_of(text, where) -> str;  FolderCases.load(manifest)   (benchmark.folders: folders of recordings
                                                       whose answer is known, judged like the world's cases)
    score(results) -> dict                            (confusion matrix, top-1, mean gap_closed)
    run_benchmark(cfg, out_dir) -> Path               (the run's record.json)
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import json
import logging
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import torch
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from handradar.atomic import atomic_write_text
from handradar.config import read_yaml
from handradar.data.convention import UNDETERMINED
from handradar.data.datasets import RecordingsFolder
from handradar.errors import FormatError, HandradarError
from handradar.gap.data import load_dataset
from handradar.gap.diagnosis import diagnose
from handradar.gap.job import check_convention, headline_metrics, write_outputs
from handradar.gap.records import benchmark_record, found, record_name, withheld, wrong_cause
from handradar.gap.report import VERDICTS
from handradar.metrics import bootstrap_gap_closed, per_example_ssim
from handradar.provenance import code_version, config_hash, machine, package_digest
from handradar.radar.chain import ChainConfig
from handradar.radar.config import RadarConfig
from handradar.runs.hydra import command_line, group_choice, output_dir
from handradar.runs.mlflow import Tracker, tracked_run
from handradar.runs.tables import fmt_number, published_command
from handradar.sim.factory import SimFactory
from handradar.viz.gap import confusion_figure
from handradar.vocab import EFFECTS
from handradar.world.config import WORLD_VERSION, world_config

log = logging.getLogger(__name__)

CONTROL_NOTHING = "nothing"
CONTROL_OUTSIDE = "iq_imbalance"  # the reference world's effect outside the vocabulary


@dataclass(frozen=True)
class Case:
    name: str
    on: tuple[str, ...]  # world effects switched on (vocabulary or not)
    truth: str  # the right attribution: an effect name, "none", or effects joined by "+" (several withheld)


def cases(names: Sequence[str]) -> list[Case]:
    """Cases by name: an effect, a control, or effects joined by "+" (withheld together, e.g.
    "sync_offset+multipath+occlusion": the realistic case, judged by the effects the selection keeps)."""
    out = []
    for n in names:
        parts = n.split("+")
        if len(parts) > 1 and all(p in EFFECTS for p in parts) and len(set(parts)) == len(parts):
            out.append(Case(n, tuple(parts), n))
        elif n in EFFECTS:
            out.append(Case(n, (n,), n))
        elif n == CONTROL_NOTHING:
            out.append(Case(n, (), "none"))
        elif n == CONTROL_OUTSIDE:
            out.append(Case(n, (CONTROL_OUTSIDE,), "none"))
        else:
            raise ValueError(f"benchmark case {n!r}: expected one of {list(EFFECTS)}, "
                             f"{CONTROL_NOTHING!r}, {CONTROL_OUTSIDE!r} or distinct effects joined by '+'")
    return out


def case_world(world: Mapping | None, case: Case, strengths: Mapping | None = None) -> dict:
    """The world config of a case: the shared settings, every vocabulary effect and the outside
    control switched off except the case's own (the world's other details keep their settings);
    ``strengths`` ({effect: {param: value}}) sets the parameters of the case's own effect."""
    w = copy.deepcopy(dict(world or {}))
    effects = dict(w.get("effects") or {})
    strengths = dict(strengths or {})
    for name in (*EFFECTS, CONTROL_OUTSIDE):
        own = dict(strengths.get(name) or {}) if name in case.on else {}
        effects[name] = {**dict(effects.get(name) or {}), **own, "enabled": name in case.on}
    w["effects"] = effects
    return w


def benchmark_world(cfg: DictConfig) -> dict:
    """The world settings every case shares: the ``world`` group, then ``benchmark.sizes[benchmark.size]``
    (when the preset names a size), then ``benchmark.world``. A size that is not a key of
    ``benchmark.sizes``, or whose settings do not give that many recordings per case, is an error."""
    bench = cfg.benchmark
    layers = [cfg.get("world") or {}]
    size = bench.get("size")
    if size is not None:
        sizes = bench.get("sizes") or {}
        if str(size) not in sizes:
            raise HandradarError(f"benchmark.size={size}: not one of the sizes in benchmark.sizes "
                                 f"({', '.join(map(str, sizes))})")
        layers.append(sizes[str(size)])
    layers.append(bench.get("world") or {})
    world = OmegaConf.to_container(OmegaConf.merge(*layers), resolve=True)
    if size is not None:
        w = world_config(world)
        n = len(w.gestures) * w.subjects * len(w.angles_deg) * w.repetitions
        if n != int(size):
            raise HandradarError(f"benchmark.size={size}: the world settings give {n} recordings per case "
                                 "(gestures x subjects x angles x repetitions); change benchmark.sizes, "
                                 "not the size's world")
    return world


@dataclass(frozen=True)
class BenchmarkWorlds:
    """The worlds of a benchmark preset: its radar and chain, the shared world settings
    (:func:`benchmark_world`; world=heldout: other physics), the withheld effects'
    ``benchmark.strengths`` and the builder (``benchmark.builder``) with its cache folder."""

    radar: RadarConfig
    chain: ChainConfig
    build: Callable[..., Path]
    world: dict
    strengths: dict
    cache_dir: Path

    @classmethod
    def from_config(cls, cfg: DictConfig) -> BenchmarkWorlds:
        from hydra.utils import get_method

        bench = cfg.benchmark
        strengths = bench.get("strengths")
        return cls(instantiate(cfg.radar), instantiate(cfg.chain), get_method(str(bench.builder)),
                   benchmark_world(cfg),
                   OmegaConf.to_container(strengths, resolve=True) if strengths is not None else {},
                   Path(cfg.paths.cache_dir) / "world")

    def config(self, case: Case) -> dict:
        """The world config of ``case`` (:func:`case_world`)."""
        return case_world(self.world, case, self.strengths)

    def dataset(self, case: Case, window_starts_s: Sequence[float] | None = None) -> Path:
        """The case's dataset (built once, cached), optionally over given windows (s)."""
        extra = {} if window_starts_s is None else {"window_starts_s": list(window_starts_s)}
        return self.build(self.config(case), self.radar, self.chain, self.cache_dir, **extra)

    def clean(self, window_starts_s: Sequence[float] | None = None) -> Path:
        """The effect-free world's dataset, optionally over another dataset's windows (s)."""
        return self.dataset(Case(CONTROL_NOTHING, (), "none"), window_starts_s)

    def setting(self, dotted: str) -> Any:
        """The shared world setting at ``dotted`` (e.g. ``scene.finger_radius_m``), defaults filled in."""
        value: Any = world_config(self.world)
        for key in dotted.split("."):
            value = getattr(value, key)
        return value

    def with_setting(self, dotted: str, value: Any) -> BenchmarkWorlds:
        """The same worlds with the shared setting at ``dotted`` set to ``value``."""
        w = copy.deepcopy(self.world)
        *head, last = dotted.split(".")
        node = w
        for key in head:
            node = node.setdefault(key, {})
        node[last] = value
        return dataclasses.replace(self, world=w)


def truth_of(text: str, where: str) -> str:
    """A folder's answer as the manifest states it: "none", an effect name, or distinct effects joined
    by "+"; anything else is a FormatError naming ``where``."""
    parts = str(text).split("+")
    if text == "none" or (all(p in EFFECTS for p in parts) and len(set(parts)) == len(parts)):
        return str(text)
    raise FormatError(where, f"truth {text!r}: expected none, one of {', '.join(EFFECTS)}, "
                             "or distinct effects joined by '+'")


@dataclass(frozen=True)
class FolderCases:
    """Folders of recordings whose withheld effects are known (``benchmark.folders``: a manifest), judged
    like the world's cases: the recordings ingested as ``diagnose.py data.root=DIR`` ingests them, no
    truth side (there is no effect-free twin of a folder).

    The manifest (YAML)::

        also_present: [tracking_jitter]   # effects every folder carries: naming them is never wrong
        folders:
          occlusion_1: {root: occ1, truth: occlusion}    # root relative to the manifest's folder
          control: {root: /data/ctrl, truth: none}       # truth: an effect, several joined by "+", or none
    """

    manifest: Path
    cases: list[Case]  # a folder's name and truth
    roots: dict[str, Path]  # by case name
    present: list[str]
    source: str | None = None  # the command that wrote the folders (the manifest's first line, "# <command>"), published

    @classmethod
    def load(cls, manifest: str | Path) -> FolderCases:
        path = Path(manifest).expanduser().resolve()
        if not path.is_file():
            raise FormatError(path, "manifest not found (benchmark.folders: a YAML file listing the folders)")
        doc = read_yaml(path)
        folders = doc.get("folders") if isinstance(doc, dict) else None
        if not isinstance(folders, dict) or not folders:
            raise FormatError(path, "expected a mapping 'folders: {name: {root: DIR, truth: EFFECT}}'")
        roots, listed = {}, []
        for name, entry in folders.items():
            if not isinstance(entry, dict) or not {"root", "truth"} <= set(entry):
                raise FormatError(path, f"folder {name!r}: expected {{root: DIR, truth: EFFECT}}, found {entry!r}")
            root = (path.parent / str(entry["root"])).expanduser()
            if not root.is_dir():
                raise FormatError(path, f"folder {name!r}: {root} is not a folder")
            roots[str(name)] = root
            listed.append(Case(str(name), (), truth_of(entry["truth"], f"{path} ({name})")))
        present = list(doc.get("also_present") or [])
        unknown = [e for e in present if e not in EFFECTS]
        if unknown:
            raise FormatError(path, f"also_present: {', '.join(map(str, unknown))} not in {', '.join(EFFECTS)}")
        first = path.read_text(encoding="utf-8").partition("\n")[0]
        return cls(path, listed, roots, present, published_command(first[2:]) if first.startswith("# ") else None)

    @property
    def label(self) -> str:
        """The record's world: ``folders-<the manifest's folder name>``."""
        return f"folders-{self.manifest.parent.name}"

    def recordings(self, case: Case, chain: ChainConfig, cache_dir: Path, skeleton_rate_hz: float) -> RecordingsFolder:
        """The case's folder, ingested as ``data=recordings`` ingests it (conf/data/recordings.yaml's defaults)."""
        return RecordingsFolder(self.roots[case.name], chain, cache_dir, skeleton_rate_hz=skeleton_rate_hz)


def score(results: Sequence[Mapping]) -> dict:
    """Confusion matrix (cases x attributions), named (top-1 correct), found (:func:`found`), wrong causes,
    inconclusive count, mean gap_closed of the withheld effects."""
    labels = [*EFFECTS, *VERDICTS]
    rows = [r["case"] for r in results]
    matrix = np.zeros((len(rows), len(labels)), dtype=int)
    for i, r in enumerate(results):
        matrix[i, labels.index(r["cause"])] = 1
    several = [r for r in results if len(withheld(r["truth"])) > 1]
    effect_cases = [r for r in results if r["truth"] != "none" and len(withheld(r["truth"])) == 1]
    controls = [r for r in results if r["truth"] == "none"]
    closed = [r["true_gap_closed"] for r in effect_cases if r.get("true_gap_closed") is not None]
    return {"labels": labels, "cases": rows, "matrix": matrix.tolist(),
            "effects_correct": sum(r["cause"] == r["truth"] for r in effect_cases), "effects_total": len(effect_cases),
            "controls_correct": sum(r["cause"] == "none" for r in controls), "controls_total": len(controls),
            "effects_inconclusive": sum(r["cause"] == "inconclusive" for r in effect_cases),
            "controls_inconclusive": sum(r["cause"] == "inconclusive" for r in controls),
            "mean_true_gap_closed": float(np.mean(closed)) if closed else None,
            "effects_found": sum(found(r) for r in effect_cases), "wrong_causes": sum(wrong_cause(r) for r in results),
            "several": [{k: r.get(k) for k in ("case", "after_effects", "kept_precision", "kept_recall",
                                                 "after_gap_closed", "reference_gap_closed")}
                        for r in several],
            "mean_after_gap_closed": float(np.mean([r["after_gap_closed"] for r in effect_cases])) if effect_cases else None}


def spectrograms(path: str | Path) -> torch.Tensor:
    """(N, doppler, columns) float32: a dataset's spectrograms."""
    with h5py.File(path, "r") as f:
        return torch.from_numpy(f["spectrograms"][()].astype(np.float32))


def window_starts(path: str | Path) -> np.ndarray:
    """(N,) the start (s) of each row's window in its recording, as the dataset stores it."""
    with h5py.File(path, "r") as f:
        return f["window_start_s"][()].astype(np.float64)


def _paired(*paths: str | Path) -> list:
    """The spectrograms of datasets whose rows pair up: same shape, and every row over the same window
    of its recording."""
    specs = [spectrograms(p) for p in paths]
    if len({tuple(s.shape) for s in specs}) != 1:
        raise ValueError(f"{', '.join(map(str, paths))}: spectrogram shapes differ {[tuple(s.shape) for s in specs]}")
    if not all(np.allclose(window_starts(paths[0]), window_starts(p)) for p in paths[1:]):
        raise ValueError(f"{', '.join(map(str, paths))}: rows cover other windows of their recordings")
    return specs


def radar_signature(case_path: str | Path, clean_path: str | Path) -> dict:
    """How much the case's effect changes the measured spectrograms: 1 - SSIM between each row of the
    case's world and the same row of the effect-free world (same seed, same gestures), both over the
    same window of each recording (``clean_path`` built at the case's windows: see :func:`truth_side`).

    Truth-side context for the table (which withheld effects are visible in the radar data at all);
    the diagnosis never sees it. Effects on the skeleton side (tracking_jitter, sync_offset) leave the
    radar data unchanged and show 0 here.
    """
    return _signature(*_paired(case_path, clean_path))


def _signature(case: torch.Tensor, clean: torch.Tensor) -> dict:
    d = 1.0 - per_example_ssim(clean, case)
    return {"signature_mean": float(np.mean(d)), "signature_median": float(np.median(d))}


def effect_reference(measured: torch.Tensor, clean: torch.Tensor, baseline: torch.Tensor,
                     candidate: torch.Tensor | None = None, *, n_boot: int = 2000, seed: int = 0) -> dict:
    """The world's own change added to the simulator: gap_closed [95 % CI] of ``baseline`` (the
    calibrated baseline simulator's spectrograms) plus, row by row, ``measured`` (the case's) minus
    ``clean`` (the effect-free world's over the same windows), clipped to [0, 1], against ``measured``.
    All (N, doppler, columns) in [0, 1].

    What a candidate that reproduced the effect exactly, on top of the simulator's generic mismatch,
    would close: the reference for the candidate's own gap_closed. It is not a strict bound (an
    effect that scales the returns the simulator already has is not additive, and a candidate can
    also close some generic gap), but an effect whose reference sits below ``min_gap_closed`` leaves
    a candidate little to be credited with. Truth-side context, never seen by the diagnosis.

    With ``candidate`` (the baseline plus the effect's candidate, same rows): ``change_correlation``,
    the Pearson r over every pixel between the candidate's change (candidate - baseline) and the
    world's (measured - clean): whether the candidate changes the spectrograms the way the effect does.
    """
    b = bootstrap_gap_closed(per_example_ssim(measured, baseline),
                             per_example_ssim(measured, (baseline + measured - clean).clamp(0.0, 1.0)),
                             n_boot=n_boot, seed=seed)
    out = {"reference_gap_closed": b.estimate, "reference_ci95": list(b.ci95)}
    if candidate is not None:
        out["change_correlation"] = change_correlation(measured - clean, candidate - baseline)
    return out


def change_correlation(world_change: torch.Tensor, candidate_change: torch.Tensor) -> float:
    """Pearson r over every pixel between the world's change and a candidate's (same shapes)."""
    pair = torch.stack([world_change.flatten().double(), candidate_change.flatten().double()])
    return float(torch.corrcoef(pair)[0, 1])


def truth_side(worlds: BenchmarkWorlds, path: Path, clean: Path, *, baseline: np.ndarray, rows: np.ndarray,
               candidate: np.ndarray | None = None, n_boot: int = 2000, seed: int = 0) -> dict:
    """A case's truth-side columns: its radar signature and the world's change on the simulator
    (:func:`effect_reference` on ``rows`` of the case, whose baseline simulator spectrograms are
    ``baseline`` and the true effect's candidate's ``candidate``: the diagnosis's evaluation rows;
    radar-side effects only).

    Row by row over the case's own windows: an effect that changes the radar data can move a row's
    window (chosen from the radar data, as ingest does), and rows over other stretches of the motion
    differ by far more than the effect (the occlusion case of world/2 at 36 recordings: signature
    0.047 with each world's own windows, 0.004 at the case's). So the effect-free world is built at
    the case's windows (``worlds.clean(window_starts_s)``) where they differ; ``windows_moved``
    counts the rows whose window the effect moved. path / clean: the case's dataset and the
    effect-free world's with its own windows.
    """
    starts = window_starts(path)
    moved = ~np.isclose(window_starts(clean), starts)
    if moved.any():
        clean = worlds.clean(starts.tolist())
    case_spec, clean_spec = _paired(path, clean)
    out = {**_signature(case_spec, clean_spec), "windows_moved": int(moved.sum())}
    if out["signature_mean"] > 0:  # skeleton-side effects leave the radar data untouched: no change to add
        measured, effect_free = case_spec[torch.as_tensor(rows)], clean_spec[torch.as_tensor(rows)]
        cand = None if candidate is None else torch.as_tensor(candidate, dtype=torch.float32)
        out.update(effect_reference(measured, effect_free, torch.as_tensor(baseline, dtype=torch.float32), cand,
                                    n_boot=n_boot, seed=seed))
    return out


def always_present(world: Mapping) -> list[str]:
    """Vocabulary effects a world has in every case whatever the case switches: tracking jitter where its
    Leap has a jitter floor (``leap.jitter_floor_m``, not an effect; world=scatterers)."""
    return ["tracking_jitter"] if world_config(world).leap.jitter_floor_m > 0 else []


def kept_scores(kept: Sequence[str], truth: str) -> dict:
    """Precision and recall of the effects the greedy selection kept against a case's withheld ones
    (precision None when nothing was kept)."""
    truths, kept = set(withheld(truth)) - {"none"}, list(kept)
    hits = len(truths.intersection(kept))
    return {"kept_precision": hits / len(kept) if kept else None,
            "kept_recall": hits / len(truths) if truths else None}


def _case_result(case: Case, report: dict, seconds: float, n_rows: int) -> dict:
    cands = {c["effect"]: c for c in report["candidates"]}
    true = cands.get(case.truth)
    top = report["candidates"][0] if report["candidates"] else None
    return {"case": case.name, "truth": case.truth, "cause": report["cause"],
            "correct": report["cause"] in withheld(case.truth),
            "top_candidate": top["effect"] if top else None, "top_gap_closed": top["gap_closed"] if top else None,
            "top_ci95": top["ci95"] if top else None,
            "true_gap_closed": None if true is None else true["gap_closed"],
            "true_ci95": None if true is None else true["ci95"],
            "true_params": None if true is None else true["params"],
            "true_rank": None if true is None else [c["effect"] for c in report["candidates"]].index(case.truth) + 1,
            "baseline_ssim": report["baseline"]["ssim"], "after_effects": report["after"]["effects"],
            "after_gap_closed": report["after"]["gap_closed"], "lead_ci95": report["evidence"].get("lead_ci95"),
            **kept_scores(report["after"]["effects"], case.truth),
            "recordings_needed": report["evidence"].get("recordings_needed"),
            "runner_up": report["evidence"].get("runner_up"), "rows": n_rows, "seconds": seconds,
            "folds": report["settings"]["folds"],  # as resolved (diagnose.folds = auto: by the rows)
            # step 0's generic settings and the mean SSIM of each grid point (not the effects' grids)
            "calibration": {k: v for k, v in (report["baseline"].get("calibration") or {}).items()
                            if k not in ("effects", "effect_grids")}}


def case_metrics(case_name: str, report: dict) -> dict[str, float]:
    """A case's headline numbers for MLflow, ``bench/<case>/<name>``; a several-effect case's "+" reads
    "-" (MLflow names take letters, digits and ``_-. :/`` only; effect names have no "-")."""
    key = case_name.replace("+", "-")
    return {f"bench/{key}/{k.split('/', 1)[1]}": v for k, v in headline_metrics(report).items()}


DEFAULT_COMMAND = "python diagnose.py +experiment=gap_benchmark"
# overrides that only say where outputs go or how progress shows: left out of the command a results file names
OUTPUT_KEYS = ("benchmark.state_dir", "benchmark.record_dir", "progress")
FIGURE = "figures/gap_confusion.png"  # in the run folder, as the run's gap_benchmark.md links it


def split_text(diag_cfg: Mapping, folds: int) -> str:
    """How the benchmark's diagnoses used the rows: one split, or cross-fitting in ``folds`` (as resolved)."""
    if folds > 1:
        return f"cross-fitting in {folds} folds, every row scored out of fold"
    return f"calibration fraction {diag_cfg.get('calibration_fraction', 0.5)}"


def _attributed(r: Mapping) -> str:
    """A case's answer; an inconclusive one with the recordings estimated to decide it."""
    if r["cause"] != "inconclusive":
        return r["cause"]
    n = r.get("recordings_needed")
    return "inconclusive (no estimate)" if n is None else f"inconclusive (~{n} recordings)"


def results_markdown(results: Sequence[Mapping], scores: Mapping, figure: str, settings: Mapping) -> str:
    sgn = functools.partial(fmt_number, signed=True)  # gap_closed figures carry their sign
    # a folder's ingest option to turn on (folders are ingested with both off); UNDETERMINED: either
    fixes = {r["case"]: "iq_swap=true or doppler_flip=true" if r["convention_fix"] == UNDETERMINED
             else f"{r['convention_fix']}=true" for r in results if r.get("convention_fix")}
    rows_are = (f"Each row is a folder of recordings listed in {settings['manifest']} with its known answer (truth), "
                "diagnosed by the paper's simulator; a control's right answer is `none`; effects every folder carries "
                "(also present) are never a wrong cause. " if settings.get("manifest") else
                "Each row is a reference world with one effect on (the other vocabulary effects off), diagnosed by the "
                "paper's simulator without that effect; `nothing` and `iq_imbalance` are controls whose right answer "
                "is `none` (no vocabulary effect / an effect outside the vocabulary). ")
    lines = ["# Gap diagnosis benchmark: withheld effects", "",
             rows_are + "Found: the true effect named, or "
             "leading an `inconclusive` verdict (with the recordings estimated to decide it); palm also by `none` or "
             "`inconclusive` with no other effect named (docs/gap_validation.md). "
             f"Generated by `{settings.get('command') or DEFAULT_COMMAND}`.", "",
             f"**Named: {scores['effects_correct']} of {scores['effects_total']} withheld effects; found: "
             f"{scores.get('effects_found', '-')} of {scores['effects_total']}; wrong causes named: "
             f"{scores.get('wrong_causes', '-')}; "
             f"controls: {scores['controls_correct']} of {scores['controls_total']} say none; inconclusive: "
             f"{scores['effects_inconclusive']} of {scores['effects_total']} withheld effects, "
             f"{scores['controls_inconclusive']} of {scores['controls_total']} controls.** "
             f"Mean gap_closed by the withheld effect: {sgn(scores['mean_true_gap_closed'])}; "
             f"by the greedy selection: {sgn(scores['mean_after_gap_closed'])}.", "",
             *[f"**Withheld together, {s['case']}**: the selection keeps {', '.join(s['after_effects']) or 'nothing'} "
               f"(precision {fmt_number(s['kept_precision'])}, recall {fmt_number(s['kept_recall'])}) and closes "
               f"{sgn(s['after_gap_closed'])} of the gap; the world's own change on the simulator closes "
               f"{sgn(s.get('reference_gap_closed'))}.\n" for s in scores.get("several", [])],
             *([f"**Against the simulator's sign convention** (re-ingest with the fix; the verdict is not the "
                "simulator's): " + ", ".join(f"{case} ({fix})" for case, fix in fixes.items()) + ".\n"]
               if fixes else []),
             "`radar signature` is 1 - SSIM between the case's spectrograms and the effect-free world's, row by row "
             "over the same window of each recording (mean / median): how visible the withheld effect is in the radar "
             "data at all. `world's change on the simulator` is the gap_closed [95 % CI] of the diagnosis's baseline "
             "simulator (its evaluation rows) plus, row by row, exactly that change (handradar.gap.benchmark.effect_reference; - where the "
             "effect leaves the radar data unchanged): what a candidate reproducing the effect would close on top of "
             "the simulator's generic mismatch, the reference for the true effect's gap_closed; r: the Pearson "
             "correlation, over every pixel, of the true effect's candidate's change with the world's (does the "
             "candidate change the spectrograms the way the effect does?).", "",
             "| world | truth | attributed cause | found | gap_closed of the true effect [95 % CI] | rank | "
             "top candidate (gap_closed) | runner-up lead CI | after: effects (gap_closed) | baseline SSIM | "
             "radar signature | world's change on the simulator |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        ci = r["true_ci95"]
        true = "-" if r["true_gap_closed"] is None else f"{sgn(r['true_gap_closed'])} [{sgn(ci[0])}, {sgn(ci[1])}]"
        sig = ("-" if r.get("signature_mean") is None
               else f"{fmt_number(r['signature_mean'])} / {fmt_number(r['signature_median'])}")
        ref = ("-" if r.get("reference_gap_closed") is None else
               f"{sgn(r['reference_gap_closed'])} [{sgn(r['reference_ci95'][0])}, {sgn(r['reference_ci95'][1])}]"
               + ("" if r.get("change_correlation") is None else f"; r {fmt_number(r['change_correlation'])}"))
        lead = "-" if not r.get("lead_ci95") else f"[{sgn(r['lead_ci95'][0])}, {sgn(r['lead_ci95'][1])}] vs {r['runner_up']}"
        lines.append(f"| {r['case']} | {r['truth']} | {_attributed(r)} | {'yes' if found(r) else 'no'} | {true} | "
                     f"{r['true_rank'] or '-'} | {r['top_candidate']} ({sgn(r['top_gap_closed'])}) | {lead} | "
                     f"{', '.join(r['after_effects']) or '-'} ({sgn(r['after_gap_closed'])}) | "
                     f"{fmt_number(r['baseline_ssim'])} | {sig} | {ref} |")
    lines += ["", f"![confusion]({figure})", "",
              f"Settings: {settings.get('rows')} rows per world ({settings.get('split')}), "
              f"{settings.get('fit_rows')} calibration rows score the grid, seed {settings.get('seed')}; "
              f"wall time {settings.get('minutes', 0):.1f} min on {settings.get('threads')} thread(s) "
              f"(code {settings.get('code_version')}).", ""]
    return "\n".join(lines)


def run_benchmark(cfg: DictConfig, out_dir: str | Path) -> Path:
    """Every case: build the world's dataset, diagnose it, score; write the figure, table, JSON and the
    compact record into ``out_dir`` (and the record into ``benchmark.record_dir`` when set)."""
    bench = cfg.benchmark
    out = Path(out_dir)
    folders = FolderCases.load(bench.folders) if bench.get("folders") else None
    worlds = None if folders else BenchmarkWorlds.from_config(cfg)
    radar, chain = (instantiate(cfg.radar), instantiate(cfg.chain)) if folders else (worlds.radar, worlds.chain)
    diag_cfg = OmegaConf.to_container(cfg.diagnose, resolve=True)
    sim_cfg = OmegaConf.to_container(cfg.sim, resolve=True)
    state = Path(bench.state_dir)
    results: list[dict] = []
    t_start = time.perf_counter()
    seed = diag_cfg.get("seed", 0)
    # the world group's choice (outside Hydra: not known); folders: their own label and their rows
    world_name = folders.label if folders else group_choice("world") or "custom"
    size = None if folders else bench.get("size")
    label = f"{world_name}_{size}" if size is not None else world_name
    tags = {"preset": cfg.task_name, "world": world_name, "size": size, "seed": seed, "code_version": code_version(),
            "run_dir": out}
    tracker = instantiate(cfg.logger) if cfg.get("logger") else Tracker("", "", enabled=False)
    with tracked_run(tracker, run_name=f"{cfg.task_name}-{label}-seed{seed}", tags=tags,
                     config=OmegaConf.to_container(cfg, resolve=True)):
        clean: Path | None = None  # the effect-free world, built on the first case that is not resumed
        present = folders.present if folders else always_present(worlds.world)
        for case in folders.cases if folders else cases(list(bench.cases)):
            recordings = (folders.recordings(case, chain, Path(cfg.paths.cache_dir) / "datasets",
                                             float(cfg.skeleton_rate_hz)) if folders else None)
            source = recordings.cache_key() if recordings else worlds.config(case)  # a folder: its files' listing
            key = config_hash("gap-benchmark-case", source, diag_cfg, sim_cfg, radar, chain,
                              package_digest())  # the package's source: a docs-only commit keeps finished cases
            done = state / f"{case.name}-{key}.json"
            if done.is_file():
                results.append({**json.loads(done.read_text()), "also_present": present})
                log.info("case %s: resumed from %s", case.name, done)
                continue
            t0 = time.perf_counter()
            path = recordings.path() if recordings else worlds.dataset(case)
            data = load_dataset(path)
            factory = SimFactory.from_config(cfg.sim, data.radar, data.chain, skeleton_rate_hz=data.skeleton_rate_hz)
            diagnosis = diagnose(data, factory, factory.effects,
                                 diag_cfg, cache_dir=Path(cfg.paths.cache_dir) / "gap",
                                 progress=bool(cfg.get("progress", True)))
            write_outputs(diagnosis, out / "cases" / case.name, data.radar, data.chain, str(path))
            res = _case_result(case, diagnosis.report, time.perf_counter() - t0, len(data))
            if recordings:  # another source's folder may break the sign convention: its verdict is not the simulator's
                res["convention_fix"] = check_convention(data).fix()
            else:
                clean = clean or worlds.clean()
                res.update(truth_side(worlds, path, clean, baseline=diagnosis.baseline, rows=diagnosis.evaluation,
                                      candidate=diagnosis.candidates.get(case.truth),
                                      n_boot=int(diag_cfg.get("n_boot", 2000)), seed=seed))
            res["seconds"], res["also_present"] = time.perf_counter() - t0, present
            atomic_write_text(done, json.dumps(res, indent=1) + "\n")
            results.append(res)
            log.info("case %s: truth %s, cause %s (%.0f s)", case.name, case.truth, res["cause"], res["seconds"])
            tracker.log_metrics(case_metrics(case.name, diagnosis.report))
        scores = score(results)
        fig = confusion_figure(np.asarray(scores["matrix"]), [f"{r['case']} ({r['truth']})" for r in results],
                               scores["labels"], out / FIGURE,
                               title=f"Gap benchmark: {scores['effects_correct']}/{scores['effects_total']} effects, "
                                     f"{scores['controls_correct']}/{scores['controls_total']} controls")
        n_rows = results[0]["rows"] if results else 0
        settings = {"rows": n_rows, "split": split_text(diag_cfg, results[0]["folds"] if results else 1),
                    "fit_rows": diag_cfg.get("fit_rows") or "all", "seed": diag_cfg.get("seed", 0),
                    "minutes": sum(r["seconds"] for r in results) / 60.0, "threads": torch.get_num_threads(),
                    "code_version": code_version(),
                    "command": published_command(command_line("diagnose.py") or DEFAULT_COMMAND, OUTPUT_KEYS),
                    **({"manifest": str(folders.manifest), "data_source": folders.source} if folders else {})}
        md_path = out / "gap_benchmark.md"
        atomic_write_text(md_path, results_markdown(results, scores, FIGURE, settings) + "\n")
        atomic_write_text(out / "benchmark.json", json.dumps({"results": results, "scores": scores,
                                                              "settings": settings}, indent=1) + "\n")
        record = benchmark_record(results, scores, settings, world=world_name, size=size,
                                  world_version="recordings" if folders else WORLD_VERSION,
                                  machine=machine(), command=settings["command"])
        rec_path = out / "record.json"
        for path in (rec_path, *([Path(bench.record_dir) / record_name(record)] if bench.get("record_dir") else [])):
            atomic_write_text(path, json.dumps(record, indent=1) + "\n")
        tracker.log_metrics({"bench/effects_correct": scores["effects_correct"],
                             "bench/controls_correct": scores["controls_correct"],
                             "bench/mean_true_gap_closed": scores["mean_true_gap_closed"] or 0.0,
                             "bench/wall_s": time.perf_counter() - t_start})
        tracker.log_artifact(fig, "figures")
        tracker.log_artifact(md_path)
        tracker.log_artifact(rec_path)
    return rec_path


def run(cfg: DictConfig) -> Path:
    """The benchmark job (``python diagnose.py +experiment=gap_benchmark``): the path of the run's record."""
    if cfg.get("threads"):
        torch.set_num_threads(int(cfg.threads))
    return run_benchmark(cfg, output_dir())
