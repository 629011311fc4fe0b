"""``python diagnose.py data.root=DIR [sim.effects=[...]]``: the job behind the entry point.

One diagnosis: the data source (``data``: recordings ingested once into a cached dataset, or the
reference world) gives a ``handradar.dataset/1`` file; the simulator is ``sim`` (its ``effects``
are the baseline, every other effect a candidate), built on the dataset's own radar and chain;
the output folder receives gap_report.json (docs/architecture.md, "Gap report"), gap_report.md and its figures;
an MLflow run (``logger``) records the config, code version, data hash, the report's headline
numbers and the files. The withheld-effect benchmark (handradar.gap.benchmark, its own job:
``+experiment=gap_benchmark`` sets ``job``) reuses the helpers below.

Public API:

    run(cfg) -> Path                       the report's path
    fit_simulator(data, sim_settings, diagnose_settings, *, cache_dir=None, effects=True,
                  progress=False) -> (Diagnosis, fitted sim settings)
                                           the one fitting path (diagnose.py and train.py's synth.fit_sim)
    write_outputs(diagnosis, out_dir, radar, chain, source="", fitted=None) -> {"json", "md", figures...}
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from pathlib import Path

from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from handradar.atomic import atomic_write_text
from handradar.data.convention import ConventionCheck, check_row
from handradar.data.datasets import file_hash
from handradar.gap.data import GapData, load_dataset
from handradar.gap.diagnosis import Diagnosis, DiagnosisConfig, diagnose
from handradar.gap.folds import check_rows
from handradar.gap.markdown import render
from handradar.gap.report import fitted_simulator, write_report
from handradar.provenance import code_version
from handradar.radar.chain import ChainConfig
from handradar.radar.config import RadarConfig
from handradar.runs.hydra import output_dir
from handradar.runs.mlflow import TAG_PREFIX, DataRef, Tracker, tracked_run
from handradar.sim.factory import SimFactory
from handradar.viz.gap import diagnosis_figures

log = logging.getLogger(__name__)


def write_outputs(diagnosis: Diagnosis, out_dir: str | Path, radar: RadarConfig, chain: ChainConfig,
                  source: str = "", fitted: Mapping | None = None) -> dict[str, Path]:
    """gap_report.json (validated), fitted_sim.yaml (``fitted``, the fitted simulator's ``sim`` settings
    from :func:`fit_simulator`; None: derived from the report alone), figures/*.png and gap_report.md
    in ``out_dir``."""

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"json": write_report(out / "gap_report.json", diagnosis.report, n_doppler=chain.n_doppler,
                                  n_columns=chain.n_columns)}
    # the fitted simulator, for train.py / handradar-synth: sim=fitted sim.from_report=<this file>
    paths["sim"] = out / "fitted_sim.yaml"
    atomic_write_text(paths["sim"], OmegaConf.to_yaml(dict(fitted) if fitted is not None
                                                        else fitted_simulator(diagnosis.report)))
    figs = diagnosis_figures(diagnosis, radar, chain, out / "figures")
    md = out / "gap_report.md"
    atomic_write_text(md, render(diagnosis.report, figs, out, source) + "\n")
    paths["md"] = md
    paths.update(figs)
    return paths


def fit_simulator(data: GapData, sim_settings: Mapping, diagnose_settings: Mapping | None = None, *,
                  cache_dir: str | Path | None = None, effects: bool = True,
                  progress: bool = False) -> tuple[Diagnosis, dict]:
    """Diagnose ``data`` with the simulator of ``sim_settings`` as the baseline and return the report
    with the fitted simulator's ``sim`` settings (:func:`handradar.gap.report.fitted_simulator`).

    effects=False: step 0 only (the calibrated baseline, no candidate is fitted or kept). Nothing is
    taken from the data's origin: every value comes from the rows of ``data``.
    """
    settings = dict(diagnose_settings or {})
    if not effects:
        settings["candidates"] = []
    build = SimFactory.from_config(sim_settings, data.radar, data.chain, skeleton_rate_hz=data.skeleton_rate_hz)
    diag = diagnose(data, build, build.effects, settings, cache_dir=cache_dir, progress=progress)
    return diag, fitted_simulator(diag.report, sim_settings)


def headline_metrics(report: dict) -> dict[str, float]:
    """Numbers of a report for MLflow (``gap/...``)."""
    m = {"gap/baseline_ssim": report["baseline"]["ssim"], "gap/baseline_mse": report["baseline"]["mse"],
         "gap/after_ssim": report["after"]["ssim"], "gap/after_gap_closed": report["after"]["gap_closed"]}
    for c in report["candidates"]:
        m[f"gap/closed_{c['effect']}"] = c["gap_closed"]
        m[f"gap/closed_{c['effect']}_ci_low"] = c["ci95"][0]
    if "radarweightnet" in report:
        m["gap/closed_radarweightnet"] = report["radarweightnet"]["gap_closed"]
    return m


def check_convention(data: GapData) -> ConventionCheck:
    """Step 0, before anything is fitted: do the rows follow the simulator's sign convention? (each
    row's Doppler centroid against its own skeleton, and the range figure ingest measured on its raw
    ADC where the dataset carries it; handradar.data.convention). Logged; a warning names the fix
    (or says that the rows cannot tell which) where something is off."""
    check = ConventionCheck(**data.read_options)
    rows = data.rows
    for i in range(len(data)):
        check.add(str(i), check_row(data.measured[i], rows.skeletons[i], rows.masks[i], rows.times,
                                    data.radar, data.chain),
                  math.nan if data.range_mirror_db is None else data.range_mirror_db[i])
    # ingest's line (if it ran) correlates over each recording's whole skeleton; this one over the rows' windows
    (log.warning if check.fix() else log.info)("diagnosed rows' %s", check.message())
    return check


def run(cfg: DictConfig) -> Path:
    """The diagnose.py job (module doc); returns the path printed as its last line."""
    import torch

    if cfg.get("threads"):
        torch.set_num_threads(int(cfg.threads))

    path = instantiate(cfg.data.dataset).path()
    data = load_dataset(path)
    settings = DiagnosisConfig.from_mapping(OmegaConf.to_container(cfg.diagnose, resolve=True))
    check_rows(data.labels, settings.folds, settings.calibration_fraction, settings.seed)  # before any output
    radar, chain = data.radar, data.chain  # simulate with the data's own radar and chain
    check_convention(data)
    sim_settings = OmegaConf.to_container(cfg.sim, resolve=True)
    out = output_dir()
    tags = {"preset": cfg.task_name, "seed": cfg.diagnose.seed, "data_path": path, "data_hash": file_hash(path),
            "code_version": code_version(), "run_dir": out}
    tracker = instantiate(cfg.logger) if cfg.get("logger") else Tracker("", "", enabled=False)
    ref = DataRef.of(OmegaConf.to_container(cfg.data, resolve=True), path, tags["data_hash"])
    with tracked_run(tracker, run_name=ref.run_name(cfg.task_name, cfg.diagnose.seed), tags=tags,
                     config=OmegaConf.to_container(cfg, resolve=True), dataset=ref):
        diag, fitted = fit_simulator(data, sim_settings, OmegaConf.to_container(cfg.diagnose, resolve=True),
                                cache_dir=Path(cfg.paths.cache_dir) / "gap", progress=bool(cfg.get("progress", True)))
        paths = write_outputs(diag, out, radar, chain, str(path), fitted)
        tracker.log_metrics(headline_metrics(diag.report))
        tracker.set_tags({f"{TAG_PREFIX}cause": diag.report["cause"]})
        for name, p in paths.items():
            tracker.log_artifact(p, "figures" if p.suffix == ".png" else None)
    log.info("cause: %s; gap closed after %s: %.3f", diag.report["cause"], diag.report["after"]["effects"],
             diag.report["after"]["gap_closed"])
    return paths["json"]
