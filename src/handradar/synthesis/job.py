"""The ``synth_fit`` job (paper Table I): modelling only vs modelling + RadarWeightNet.

``python train.py +experiment=synth_fit`` fits RadarWeightNet to the measured spectrograms of a
training split (the paper's schedule, CPU-sized data: ``synth.max_train_rows``) and reports, on
held-out rows, SSIM and MSE against the measurement of the modelling-only simulator and of the
RadarWeightNet-enhanced one: ``test/ssim_model``, ``test/ssim_enhanced``, ``test/mse_model``,
``test/mse_enhanced``. Four generalisation fits repeat this across a shift (suffixes):

- ``_hands``: trained on single-hand rows, tested on two-hand rows;
- ``_occlusion``: trained without occlusion, tested with;
- ``_angle``: trained at 0 deg, tested at +/-30 deg;
- ``_subject``: tested on subjects never seen in training.

Each fit is resumable (state folder of the job) and finished fits are not redone. The main fit's
network is saved as ``<run_dir>/radarweightnet.pt`` (``handradar-synth synth.weights=...``), and
figures go to ``<run_dir>/figures`` and MLflow.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf

from handradar.data.splits import default_train_values, ood_field, stratified_sample
from handradar.synthesis.fit import (
    Pairs,
    fit_weight_net,
    load_pairs,
    load_weight_net,
    predict,
    save_weight_net,
    schedule,
    synth_scores,
)
from handradar.synthesis.providers import cache_rows, dataset_simulator
from handradar.training import TrackerLogger
from handradar.viz.weightnet import (
        plot_comparison,
        plot_decomposition,
        plot_weights,
    )

log = logging.getLogger(__name__)

SHIFTS = ("hands", "occlusion", "angle", "subject")


def synth_splits(labels: np.ndarray, meta: dict[str, np.ndarray], seed: int, *, test_fraction: float,
                 max_train_rows: int, max_test_rows: int, shifts: tuple[str, ...] = SHIFTS) -> dict[str, tuple]:
    """{suffix: (train rows, test rows)}; suffix "" is the in-distribution split.

    Training rows are capped at ``max_train_rows`` and test rows at ``max_test_rows`` by stratified
    sampling (per gesture), so every fit costs about the same on a CPU.
    """
    every = np.arange(len(labels))

    def cap(rows: np.ndarray, n: int, salt: int) -> np.ndarray:
        if len(rows) <= n:
            return rows
        return stratified_sample(labels, n / len(rows), seed + salt, rows)

    test = stratified_sample(labels, test_fraction, seed)
    out = {"": (cap(np.setdiff1d(every, test), max_train_rows, 1), cap(test, max_test_rows, 2))}
    for k, shift in enumerate(shifts):
        field = ood_field(shift)
        if field not in meta:
            log.warning("synth_fit: no meta field %r, skipping the %s generalisation", field, shift)
            continue
        values = meta[field]
        try:
            inside = np.isin(values, default_train_values(shift, values, seed))
        except ValueError as exc:  # e.g. one subject only: this shift cannot be formed from the data
            log.warning("synth_fit: skipping the %s generalisation (%s)", shift, exc)
            continue
        tr, te = np.flatnonzero(inside), np.flatnonzero(~inside)
        if len(tr) and len(te):
            out[f"_{shift}"] = (cap(tr, max_train_rows, 10 + k), cap(te, max_test_rows, 20 + k))
    return out


def run_synth_fit(job) -> dict[str, float]:
    """Job kind for train.py (``job: handradar.synthesis.job.run_synth_fit``)."""


    cfg, real = job.cfg, job.real
    sc = cfg.synth_fit
    sim = dataset_simulator(real.path, cfg.sim)
    splits = synth_splits(real.y, real.meta, job.seed, test_fraction=float(sc.test_fraction),
                          max_train_rows=int(sc.max_train_rows), max_test_rows=int(sc.max_test_rows))
    # every row is cached (not only the splits' union): the cache key is then the dataset's, shared
    # with the gap diagnosis and later fits
    rows = np.arange(len(real.y))
    log.info("synth_fit: caching features and slot profiles of %d rows", len(rows))
    caches = cache_rows(real.path, rows, sim, Path(cfg.synth.cache_dir), features=True,
                        n_jobs=int(sc.get("n_jobs", 2)), progress=True)
    targets = real.x

    def pairs(sel: np.ndarray) -> Pairs:
        return load_pairs(caches, targets, sel)

    phases = schedule(sc.phases)
    net_kwargs = OmegaConf.to_container(sc.net, resolve=True) if sc.get("net") else {}
    metrics: dict[str, float] = {}
    for suffix, (train, test) in splits.items():
        name = f"synth_fit{suffix or '_main'}"
        weights_file = job.state / name / "radarweightnet.pt"

        def compute(train=train, test=test, name=name, weights_file=weights_file) -> dict:
            net = fit_weight_net(sim, pairs(train), phases=phases, seed=job.seed, net_kwargs=net_kwargs,
                                 ckpt_dir=job.state / name / "checkpoints",
                                 logger=TrackerLogger(job.tracker, prefix=f"{name}/"))
            save_weight_net(weights_file, net, sim, net_kwargs)
            scores = synth_scores(sim, net, pairs(test))
            log.info("%s: %s (train %d, test %d rows)", name, scores, len(train), len(test))
            return {**scores, "n_train": int(len(train)), "n_test": int(len(test))}

        result = job.cached(name, compute)
        metrics.update({f"test/{k}{suffix}": v for k, v in result.items() if not k.startswith("n_")})
    if job.rank_zero:
        main = job.state / "synth_fit_main" / "radarweightnet.pt"
        out = job.run_dir / "radarweightnet.pt"
        out.write_bytes(main.read_bytes())
        job.tracker.log_artifact(out, "model")
        net, _ = load_weight_net(out)
        _figures(job, sim, net, pairs(splits[""][1][:8]), real)
    return metrics


def _figures(job, sim, net, test: Pairs, real) -> None:
    """Measured / modelled / enhanced spectrograms, the per-reflection-point decomposition, weights."""

    figs = job.run_dir / "figures"
    model = predict(sim, None, test)
    enhanced = predict(sim, net, test)
    names = [str(real.meta["gesture"][r]) if "gesture" in real.meta else str(r) for r in test.rows]
    paths = [plot_comparison(test.targets.numpy(), model.numpy(), enhanced.numpy(), names,
                             figs / "measured_model_enhanced.png")]
    with torch.no_grad():
        weights = net(test.features[:1], test.masks[:1])[0].numpy()
    paths.append(plot_decomposition(sim, test.subset([0]), weights, figs / "reflection_point_decomposition.png",
                                    title=names[0]))
    paths.append(plot_weights(weights, test.masks[0].numpy(), figs / "learned_weights.png", title=names[0]))
    for p in paths:
        job.tracker.log_artifact(p, "figures")
