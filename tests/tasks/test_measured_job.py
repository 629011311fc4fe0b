"""The measured job end to end (handradar.tasks.measured) on a small measured stand-in: the fit, the variants,
the metrics of each split, the unpaired gap report; and K = 0 (synthetic only)."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from handradar.data.unknowns import MOTION, UNKNOWNS
from handradar.tasks.measured import MeasuredRows, MeasuredSetup, label_budget
from handradar.tasks.train import run
from handradar.vocab import MEASURED_VARIANTS
from tests.synthesis.test_measured_fit import TRUTH, measured_stand_in
from tests.tasks.fakes import compose_train


def overrides(tmp_path, manifest, *extra: str) -> list[str]:
    return ["+experiment=measured", f"data.manifest={manifest}", f"paths.log_dir={tmp_path}/logs",
            f"paths.cache_dir={tmp_path}/cache", "model.net.channels=[8,16]",
            "logger=none", "checkpoint_interval_s=0", "recipe.epochs=2", "recipe.min_steps=6", "print_table=false",
            "trainer.enable_progress_bar=false", "split.val_per_class=2", "synth.measured.per_class=4",
            "synth.measured.fit.per_class=8", "synth.measured.fit.n_boot=20",
            "synth.measured.fit.grid.v_max_m_s=[2.0,4.0]", "synth.measured.fit.grid.frame_period_s=[0.04]",
            "synth.measured.fit.grid.dynamic_range_db=[20.0]", *extra]


def test_measured_job(tmp_path):
    measured_stand_in(tmp_path / "data")
    cfg = compose_train(overrides(tmp_path, tmp_path / "data" / "m.yaml", "split.per_class=2"))
    run_dir = run(cfg, tmp_path / "run")
    metrics = json.loads((run_dir / "metrics.json").read_text())
    variants = ["radar_only", "model_synth", "model_synth_only", "synth_pretrain"]
    assert set(metrics) == {f"val/acc_{v}" for v in variants} | {f"test/acc_{v}_test" for v in variants}
    assert all(0.0 <= v <= 1.0 for v in metrics.values())
    # the unknowns were fitted on the training rows outside validation; the stand-in's truth among the candidates
    fit = json.loads(next((tmp_path / "cache" / "synth").glob("measured-fit-*.json")).read_text())
    assert fit["values"]["approaching"] == TRUTH["approaching"] and fit["values"]["v_max_m_s"] == TRUTH["v_max_m_s"]
    report = json.loads((run_dir / "unpaired_gap.json").read_text())
    assert set(report["classes"]) == {"push", "pull", "swipe"} and (run_dir / "figures" / "class_means.png").is_file()
    assert {f"confusion_{v}_{part}.png" for v in variants for part in ("val", "test")} <= {
        f.name for f in (run_dir / "figures").iterdir()}
    # K = 0: synthetic only; the fit is reused from its cache
    cfg0 = compose_train(overrides(tmp_path, tmp_path / "data" / "m.yaml", "split.per_class=0"))
    metrics0 = json.loads((run(cfg0, tmp_path / "run0") / "metrics.json").read_text())
    assert set(metrics0) == {"val/acc_model_synth_only", "test/acc_model_synth_only_test"}
    # the synthetic-only classifier is shared by every K of a seed: cached beside the synthetic rows, not retrained
    assert metrics0["test/acc_model_synth_only_test"] == metrics["test/acc_model_synth_only_test"]
    assert len(list((tmp_path / "cache" / "synth").glob("measured-synth-*-classifier-*.pt"))) == 1


def test_no_variant_is_the_report_alone(tmp_path):
    """variants=[]: the fit, the synthetic rows and the unpaired gap report, no classifier trained."""
    measured_stand_in(tmp_path / "data")
    cfg = compose_train(overrides(tmp_path, tmp_path / "data" / "m.yaml", "split.per_class=0", "variants=[]"))
    run_dir = run(cfg, tmp_path / "run")
    assert json.loads((run_dir / "metrics.json").read_text()) == {}
    assert set(json.loads((run_dir / "unpaired_gap.json").read_text())["classes"]) == {"push", "pull", "swipe"}
    assert not list((tmp_path / "cache" / "synth").glob("*classifier*"))
    assert not (run_dir / "figures" / "confusion_radar_only_val.png").exists()


def test_unknown_variant_is_one_line(tmp_path):
    measured_stand_in(tmp_path / "data")
    cfg = compose_train(overrides(tmp_path, tmp_path / "data" / "m.yaml", "variants=[cgan]"))
    with pytest.raises(ValueError, match="unknown measured variant 'cgan'"):
        run(cfg, tmp_path / "run")


def test_real_share_of_the_batches(tmp_path, capsys):
    measured_stand_in(tmp_path / "data")
    extra = ("split.per_class=2", "variants=[model_synth]", "synth.measured.fit.grid.chirps_per_frame=[16]",
             "synth.measured.fit.grid.noise_db=[null]")
    cfg = compose_train(overrides(tmp_path, tmp_path / "data" / "m.yaml", *extra, "synth.measured.real_share=0.5",
                                  "print_table=true"))
    metrics = json.loads((run(cfg, tmp_path / "run") / "metrics.json").read_text())
    assert set(metrics) == {"val/acc_model_synth", "test/acc_model_synth_test"}
    # the table the job prints reads the variants, splits and K the job logged
    assert f"| 2 per class, test {{measured: m}} | – | {metrics['test/acc_model_synth_test']:.3f} |" in capsys.readouterr().out
    cfg = compose_train(overrides(tmp_path, tmp_path / "data" / "m.yaml", *extra, "synth.measured.real_share=1.5"))
    with pytest.raises(ValueError, match=r"real_share must lie in \(0, 1\)"):
        run(cfg, tmp_path / "run2")


def test_synthetic_only_adapts_batchnorm_to_the_fit_rows(tmp_path, monkeypatch):
    """synth.measured.adapt_bn (AdaBN): the synthetic-only classifier's BatchNorm statistics are recomputed on the
    unlabelled measured rows the fit sees (the training users' rows outside validation), and only when set."""
    import handradar.tasks.measured as measured_job

    seen, recompute = [], measured_job.recompute_bn_stats
    monkeypatch.setattr(measured_job, "recompute_bn_stats",
                        lambda net, x, **kw: (seen.append(len(x)), recompute(net, x, **kw))[1])
    measured_stand_in(tmp_path / "data")
    for adapt in ("true", "false"):
        cfg = compose_train(overrides(tmp_path, tmp_path / "data" / "m.yaml", "split.per_class=0",
                                      f"synth.measured.adapt_bn={adapt}"))
        run(cfg, tmp_path / f"run-{adapt}")
    fit = json.loads(next((tmp_path / "cache" / "synth").glob("measured-fit-*.json")).read_text())
    assert seen == [fit["n_rows"]]


def test_fit_keeps_the_labelled_budget(tmp_path, monkeypatch):
    """fit.rows=unlabelled (the default) hands the fit the pool's images without a label (one pooled class, at any
    K); fit.rows=labelled the job's K rows per class with theirs. Nothing else reaches the fit."""
    import handradar.tasks.measured as measured_job

    seen, fit = [], measured_job.fit_unknowns
    monkeypatch.setattr(measured_job, "fit_unknowns",
                        lambda x, y, n, *a, **kw: (seen.append((len(x), sorted(set(y.tolist())), n)), fit(x, y, n, *a, **kw))[1])
    measured_stand_in(tmp_path / "data")
    for rows in ("unlabelled", "labelled"):
        cfg = compose_train(overrides(tmp_path, tmp_path / "data" / "m.yaml", "split.per_class=2", "variants=[model_synth]",
                                      f"synth.measured.fit.rows={rows}"))
        run(cfg, tmp_path / f"run-{rows}")
    # 3 classes of 9 training rows, 2 of each for validation: a pool of 21 rows; K = 2: 6 labelled rows
    assert seen == [(21, [0], 1), (6, [0, 1, 2], 3)]


def test_motions_are_fitted_only_when_asked(tmp_path, monkeypatch):
    """By default the motion unknowns reach the fit at their prior alone (the manifest's motion_ranges as they are);
    synth.measured.fit.motions=true hands it their grids; a set value is fixed either way."""
    import handradar.tasks.measured as measured_job

    grids = []

    class Seen(Exception):
        pass

    def capture(x, y, n, simulate, grid, **kw):
        grids.append(grid)
        raise Seen  # the grid is all this test needs

    monkeypatch.setattr(measured_job, "fit_unknowns", capture)
    measured_stand_in(tmp_path / "data")
    for extra in ([], ["synth.measured.fit.motions=true", "synth.measured.unknowns.hand_size_factor=1.15"]):
        cfg = compose_train(overrides(tmp_path, tmp_path / "data" / "m.yaml", "split.per_class=0", *extra))
        with pytest.raises(Seen):
            run(cfg, tmp_path / f"run-{len(extra)}")
    assert {k: grids[0][k] for k in MOTION} == {k: [UNKNOWNS[k].identity] for k in MOTION}
    assert {k: grids[1][k] for k in MOTION} == {**{k: list(UNKNOWNS[k].grid) for k in MOTION},
                                                "hand_size_factor": [1.15]}


def test_setup_is_checked_before_any_fit(tmp_path, monkeypatch):
    import handradar.tasks.measured as measured_job

    monkeypatch.setattr(measured_job, "fit_unknowns", lambda *a, **kw: pytest.fail("the fit ran before the check"))
    measured_stand_in(tmp_path / "data")
    for extra, message in [(("split.per_class=0", "synth.measured.fit.rows=labelled"), "K = 0 has none"),
                           (("synth.measured.real_share=1.5",), r"real_share must lie in \(0, 1\)"),
                           (("synth.measured.fit.rows=pool",), "fit.rows must be one of"),
                           (("split.per_class=-1",), "split.per_class must be a count >= 0 or all")]:
        cfg = compose_train(overrides(tmp_path, tmp_path / "data" / "m.yaml", *extra))
        with pytest.raises(ValueError, match=message):
            run(cfg, tmp_path / "run")


def test_each_variant_budget():
    """What each variant uses, with labels and without, at K = 2 of 3 classes and a pool of 21 rows."""
    rows = MeasuredRows(train=np.arange(6), val=np.arange(6), pool=np.arange(21), tests={})
    setup = MeasuredSetup(per_class=2, val_per_class=2, test_seed=0, variants=tuple(MEASURED_VARIANTS),
                          fit_rows="unlabelled", real_share=0.5, adapt_bn=True, synth_per_class=4)
    assert label_budget(setup, rows) == {"radar_only": {"labelled": 6, "unlabelled": 0},
                                         "model_synth": {"labelled": 6, "unlabelled": 21},
                                         "synth_pretrain": {"labelled": 6, "unlabelled": 21},
                                         "model_synth_only": {"labelled": 0, "unlabelled": 21}}
    labelled = label_budget(replace(setup, fit_rows="labelled", adapt_bn=False), rows)
    assert labelled["model_synth_only"] == {"labelled": 6, "unlabelled": 0} and labelled["model_synth"]["unlabelled"] == 0
