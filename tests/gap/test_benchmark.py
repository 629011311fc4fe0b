"""The withheld-effect benchmark: case worlds, scoring, and the whole run on a stand-in world."""

from __future__ import annotations

import json
import re

import h5py
import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from handradar.data.hdf5 import open_writer
from handradar.errors import FormatError
from handradar.gap.benchmark import (
    CONTROL_NOTHING,
    BenchmarkWorlds,
    Case,
    FolderCases,
    case_world,
    cases,
    effect_reference,
    radar_signature,
    results_markdown,
    run_benchmark,
    score,
    split_text,
    window_starts,
)
from handradar.gap.records import found, validate_record, wrong_cause
from handradar.sim.effects import REGISTRY
from handradar.vocab import EFFECTS as EFFECT_NAMES
from handradar.world.config import WORLD_VERSION
from tests.data.writer import Scene, write_recording
from tests.gap.conftest import rows, simulate

CALLS: list[dict] = []


def test_cases_switch_one_effect_and_keep_other_settings():
    cs = cases(["palm", "nothing", "iq_imbalance"])
    assert [(c.name, c.truth) for c in cs] == [("palm", "palm"), ("nothing", "none"), ("iq_imbalance", "none")]
    w = case_world({"subjects": 2, "effects": {"noise": {"snr_db": 5.0}, "dropouts": {"enabled": False}}}, cs[0])
    assert w["subjects"] == 2 and w["effects"]["palm"]["enabled"] is True
    assert all(w["effects"][n]["enabled"] is False for n in EFFECT_NAMES if n != "palm")
    assert w["effects"]["noise"]["snr_db"] == 5.0 and w["effects"]["dropouts"] == {"enabled": False}
    assert w["effects"]["iq_imbalance"]["enabled"] is False
    assert case_world({}, cs[2])["effects"]["iq_imbalance"]["enabled"] is True
    # a case's strength applies to its own effect only
    strong = {"palm": {"thickness_m": 0.04}, "noise": {"snr_db": -3.0}}
    w = case_world({"effects": {"noise": {"snr_db": 5.0}}}, cs[0], strong)
    assert w["effects"]["palm"] == {"thickness_m": 0.04, "enabled": True}
    assert w["effects"]["noise"] == {"snr_db": 5.0, "enabled": False}


def test_worlds_read_and_move_one_shared_setting(radar, short_chain, tmp_path):
    """BenchmarkWorlds.setting reads a shared world setting with the generator's defaults filled in;
    with_setting moves it in a copy (the phase-twin probe), leaving the original and the cases'
    effect switches as they were."""
    worlds = BenchmarkWorlds(radar, short_chain, lambda *a, **k: tmp_path, {"scene": {"facet_turn": 0.5}}, {},
                             tmp_path)
    assert worlds.setting("scene.finger_radius_m") == 0.0085 and worlds.setting("scene.facet_turn") == 0.5
    twin = worlds.with_setting("scene.finger_radius_m", 0.009)
    assert twin.setting("scene.finger_radius_m") == 0.009 and twin.setting("scene.facet_turn") == 0.5
    assert worlds.setting("scene.finger_radius_m") == 0.0085 and "finger_radius_m" not in worlds.world["scene"]
    (palm,) = cases(["palm"])
    assert twin.config(palm)["effects"] == worlds.config(palm)["effects"]
    assert twin.with_setting("seed", 7).setting("seed") == 7


def test_score_counts_effects_and_controls():
    res = [{"case": "palm", "truth": "palm", "cause": "palm", "true_gap_closed": 0.3, "after_gap_closed": 0.4},
           {"case": "noise", "truth": "noise", "cause": "none", "true_gap_closed": 0.1, "after_gap_closed": 0.2},
           {"case": "nothing", "truth": "none", "cause": "none", "true_gap_closed": None, "after_gap_closed": 0.0}]
    s = score(res)
    assert (s["effects_correct"], s["effects_total"], s["controls_correct"], s["controls_total"]) == (1, 2, 1, 1)
    assert abs(s["mean_true_gap_closed"] - 0.2) < 1e-12
    m = np.asarray(s["matrix"])
    assert m.sum() == 3 and m[0, s["labels"].index("palm")] == 1 and m[1, s["labels"].index("none")] == 1


def test_inconclusive_shows_its_estimate_and_counts_as_found_only_when_it_leads_with_the_truth():
    res = [{"case": "palm", "truth": "palm", "cause": "inconclusive", "correct": False, "recordings_needed": 620},
           {"case": "noise", "truth": "noise", "cause": "noise", "correct": True, "recordings_needed": None},
           {"case": "nothing", "truth": "none", "cause": "inconclusive", "correct": False, "recordings_needed": None},
           {"case": "iq_imbalance", "truth": "none", "cause": "none", "correct": True, "recordings_needed": None}]
    for r in res:
        r.update(true_gap_closed=None if r["truth"] == "none" else 0.03, after_gap_closed=0.0, true_ci95=[0.0, 0.06],
                 true_rank=1, top_candidate="palm", top_gap_closed=0.03, lead_ci95=None, after_effects=[],
                 baseline_ssim=0.9)
    s = score(res)
    assert (s["effects_correct"], s["effects_found"], s["controls_correct"], s["wrong_causes"]) == (1, 2, 1, 0)
    assert (s["effects_inconclusive"], s["controls_inconclusive"]) == (1, 1)
    m = np.asarray(s["matrix"])
    assert m[0, s["labels"].index("inconclusive")] == 1 and m[2, s["labels"].index("inconclusive")] == 1
    md = results_markdown(res, s, "gap_confusion.png", {})
    assert "| palm | palm | inconclusive (~620 recordings) | yes |" in md  # found: it leads, undecided
    assert "| nothing | none | inconclusive (no estimate) | no |" in md
    assert "Named: 1 of 2 withheld effects; found: 2 of 2; wrong causes named: 0; controls: 1 of 2 say none" in md
    assert "Generated by `python diagnose.py +experiment=gap_benchmark`." in md  # no command known: the preset's
    cmd = "python diagnose.py +experiment=gap_benchmark benchmark.size=36 diagnose.folds=1"
    assert f"Generated by `{cmd}`." in results_markdown(res, s, "gap_confusion.png", {"command": cmd})


@pytest.mark.parametrize("truth, cause, top, kept, is_found, is_wrong", [
    ("occlusion", "occlusion", "occlusion", ["occlusion"], True, False),
    ("occlusion", "inconclusive", "occlusion", [], True, False),      # leads, undecided
    ("occlusion", "inconclusive", "multipath", [], False, False),
    ("occlusion", "none", "occlusion", [], False, False),             # a missed effect, not a false cause
    ("occlusion", "multipath", "multipath", ["multipath"], False, True),
    ("palm", "none", "noise", [], True, False),                       # palm: must not mislead
    ("palm", "inconclusive", "noise", [], True, False),
    ("palm", "inconclusive", "noise", ["noise"], False, False),       # another effect kept: misleading
    ("palm", "inconclusive", "noise", None, False, False),            # a record that cannot show what was kept
    ("palm", "noise", "noise", ["noise"], False, True),
    ("none", "none", "noise", [], True, False),
    ("none", "inconclusive", "noise", [], False, False),
    ("none", "occlusion", "occlusion", ["occlusion"], False, True),
])
def test_how_a_case_is_judged(truth, cause, top, kept, is_found, is_wrong):
    case = {"truth": truth, "cause": cause, "top_candidate": top, "after_effects": kept}
    assert (found(case), wrong_cause(case)) == (is_found, is_wrong)


@pytest.mark.parametrize("truth, cause, top, kept, is_found, is_wrong", [
    ("occlusion", "tracking_jitter", "tracking_jitter", ["tracking_jitter"], False, False),  # the floor: not wrong
    ("occlusion", "tracking_jitter", "tracking_jitter", ["tracking_jitter", "occlusion"], True, False),  # kept
    ("occlusion", "multipath", "multipath", ["multipath"], False, True),
    ("palm", "inconclusive", "tracking_jitter", ["tracking_jitter"], True, False),  # nothing but the floor kept
    ("palm", "tracking_jitter", "tracking_jitter", ["tracking_jitter"], True, False),  # the floor named: as "none"
    ("palm", "tracking_jitter", "tracking_jitter", ["tracking_jitter", "noise"], False, False),  # noise kept: misleads
    ("palm", "noise", "noise", ["noise"], False, True),
    ("none", "tracking_jitter", "tracking_jitter", ["tracking_jitter"], True, False),
])
def test_a_jitter_floor_in_every_case_is_never_a_wrong_cause(truth, cause, top, kept, is_found, is_wrong):
    from handradar.gap.benchmark import always_present
    assert always_present({}) == [] and always_present({"leap": {"jitter_floor_m": 0.0004}}) == ["tracking_jitter"]
    case = {"truth": truth, "cause": cause, "top_candidate": top, "after_effects": kept,
            "also_present": ["tracking_jitter"]}
    assert (found(case), wrong_cause(case)) == (is_found, is_wrong)


def _spectrogram_file(path, spec, starts=None):
    with h5py.File(path, "w") as f:
        f["spectrograms"] = np.clip(spec, 0.0, 1.0).astype(np.float32)
        f["window_start_s"] = np.zeros(len(spec)) if starts is None else np.asarray(starts, np.float64)
    return path


def test_settings_line_says_how_the_rows_were_used():
    assert split_text({"calibration_fraction": 0.6}, 1) == "calibration fraction 0.6"
    # the folds as the diagnosis resolved them (diagnose.folds = auto), not as configured
    assert split_text({"folds": "auto", "calibration_fraction": 0.5}, 3) == ("cross-fitting in 3 folds, every row "
                                                                             "scored out of fold")


def test_effect_reference_adds_the_worlds_change_to_the_simulator():
    """The reference column: the world's change (case minus effect-free) added to the simulator's
    baseline. A change that is all the gap closes it whole; one the simulator already has (the
    effect-free world equal to the case) closes nothing; half of a change closes a part."""
    rng = np.random.default_rng(0)
    sim = torch.from_numpy(0.5 * rng.random((12, 64, 32)).astype(np.float32))
    blob = torch.zeros(64, 32)
    blob[20:40, 4:20] = 0.4
    case = sim + blob
    whole = effect_reference(case, sim, sim, n_boot=300)
    assert whole["reference_gap_closed"] > 0.99 and whole["reference_ci95"][0] > 0.99
    assert abs(effect_reference(case, case, sim, n_boot=300)["reference_gap_closed"]) < 1e-6
    half = effect_reference(case, sim + blob / 2, sim, n_boot=300)["reference_gap_closed"]
    assert 0.1 < half < 0.99
    # a candidate that adds the blob changes the spectrograms as the world does; one that removes it, the other way
    assert effect_reference(case, sim, sim, sim + 0.5 * blob, n_boot=300)["change_correlation"] == pytest.approx(1.0)
    assert effect_reference(case, sim, sim, sim - blob, n_boot=300)["change_correlation"] == pytest.approx(-1.0)


def test_truth_side_comparisons_refuse_rows_over_other_windows(tmp_path):
    """Rows over other stretches of their recordings differ by more than any effect: the signature
    compares a case with the effect-free world built at its own windows, and refuses anything else."""
    x = np.random.default_rng(0).random((6, 64, 32))
    case = _spectrogram_file(tmp_path / "case.h5", x, [0.0, 0.1, 0.2, 0.0, 0.0, 0.0])
    same = _spectrogram_file(tmp_path / "same.h5", x, [0.0, 0.1, 0.2, 0.0, 0.0, 0.0])
    moved = _spectrogram_file(tmp_path / "moved.h5", x, [0.0, 0.1, 0.3, 0.0, 0.0, 0.0])
    assert radar_signature(case, same)["signature_mean"] < 1e-6
    with pytest.raises(ValueError, match="other windows"):
        radar_signature(case, moved)
    with pytest.raises(ValueError, match="shapes differ"):
        radar_signature(case, _spectrogram_file(tmp_path / "short.h5", x[:5], [0.0] * 5))


def fake_world(world_cfg, radar, chain, cache_dir, window_starts_s=None):
    """A stand-in for handradar.world.build_world_dataset: the simulator with the world's enabled
    vocabulary effects (antenna_pattern at q = 6) makes the 'measured' spectrograms. Like the world's,
    its windows follow the radar data: with antenna_pattern on, every row's starts at 0.1 s, else at 0."""
    CALLS.append({**world_cfg, "window_starts_s": window_starts_s})
    on = [n for n, e in world_cfg["effects"].items() if e.get("enabled") and n in EFFECT_NAMES]
    starts = window_starts_s or [0.1 if "antenna_pattern" in on else 0.0] * 8
    rs, labels, meta = rows(radar, chain, 8, seed=5)
    spec = simulate(radar, chain, rs, {n: ({"q": 6.0} if n == "antenna_pattern" else {}) for n in on})
    cache_dir.mkdir(parents=True, exist_ok=True)
    return _dataset_file(cache_dir / f"fake_{'_'.join(on) or 'none'}{'_aligned' if window_starts_s else ''}.h5",
                         spec, rs, labels, meta, radar, chain, starts)


def _dataset_file(path, spec, rs, labels, meta, radar, chain, starts=None):
    """A handradar.dataset/1 file of the rows ``rs`` with spectrograms ``spec`` and window starts (s)."""
    with open_writer(path, classes=["g0", "g1", "g2", "g3"], radar=radar, chain=chain, skeleton_rate_hz=100.0,
                     n_steps=rs.skeletons.shape[1], config_hash="fake") as w:
        for i in range(len(rs)):
            w.append(spec[i], int(labels[i]), rs.skeletons[i], rs.masks[i], 0.0 if starts is None else starts[i],
                     {"gesture": str(meta["gesture"][i]), "hands": int(meta["hands"][i]), "subject": str(meta["subject"][i])})
    return path


@pytest.mark.slow
def test_benchmark_runs_scores_and_resumes(tmp_path, radar, short_chain):
    cfg = OmegaConf.create({
        "task_name": "gap_benchmark", "progress": False, "radar": {"_target_": "handradar.radar.config.RadarConfig.from_cfg_text",
                                                                   "text": radar.to_cfg(), "source": "test"},
        "chain": {"_target_": "handradar.radar.chain.ChainConfig", "n_columns": short_chain.n_columns},
        "paths": {"cache_dir": str(tmp_path / "cache")},
        "sim": {"_target_": "handradar.sim.simulator.Simulator", "_partial_": True, "effects": [], "effect_params": {}},
        "diagnose": {"candidates": ["antenna_pattern", "palm"], "radarweightnet": False, "n_boot": 300, "greedy_max": 1},
        "world": {"seed": 7, "subjects": 3},  # the world group: benchmark.world goes on top
        "benchmark": {"builder": "tests.gap.test_benchmark.fake_world",
                      "cases": ["antenna_pattern", "nothing"], "world": {"subjects": 1},
                      "state_dir": str(tmp_path / "state"), "record_dir": str(tmp_path / "results")}})
    CALLS.clear()
    rec_path = run_benchmark(cfg, tmp_path / "run")
    md = tmp_path / "run" / "gap_benchmark.md"  # every output in the run folder, the record also kept aside
    assert rec_path == tmp_path / "run" / "record.json" and md.is_file()
    assert (tmp_path / "run" / "figures" / "gap_confusion.png").is_file() and "](figures/gap_confusion.png)" in md.read_text()
    record = validate_record(json.loads(rec_path.read_text()), str(rec_path))
    assert json.loads((tmp_path / "results" / "custom_8.json").read_text()) == record  # outside Hydra: world "custom"
    assert record["world_version"] == WORLD_VERSION and record["seeds"] == [0] and record["size"] == 8
    assert [c["cause"] for c in record["cases"]] == ["antenna_pattern", "none"] and record["scores"]["effects_correct"] == 1
    out = json.loads((tmp_path / "run" / "benchmark.json").read_text())
    by = {r["case"]: r for r in out["results"]}
    assert by["antenna_pattern"]["cause"] == "antenna_pattern" and by["nothing"]["cause"] == "none"
    assert out["scores"]["effects_correct"] == 1 and out["scores"]["controls_correct"] == 1
    assert "| antenna_pattern | antenna_pattern | antenna_pattern | yes |" in md.read_text()  # found
    assert (tmp_path / "run" / "cases" / "antenna_pattern" / "gap_report.json").is_file()
    # 2 cases + the effect-free world, once with its own windows and once with antenna_pattern's (they differ)
    assert len(CALLS) == 4 and all(c["subjects"] == 1 and c["seed"] == 7 for c in CALLS)
    aligned = [c for c in CALLS if c["window_starts_s"] is not None]
    assert len(aligned) == 1 and aligned[0]["window_starts_s"] == [0.1] * 8 and aligned[0]["effects"]["antenna_pattern"]["enabled"] is False
    assert (by["antenna_pattern"]["windows_moved"], by["nothing"]["windows_moved"]) == (8, 0)
    assert by["nothing"]["signature_mean"] < 1e-6 < by["antenna_pattern"]["signature_mean"]
    # the world's antenna change added to the diagnosis's baseline (the simulator without it) closes
    # the gap; the control has no change to add
    assert by["antenna_pattern"]["reference_ci95"][0] > 0.5 and by["nothing"].get("reference_gap_closed") is None
    assert by["antenna_pattern"]["change_correlation"] > 0.5  # the fitted candidate is the world's own effect
    CALLS.clear()
    run_benchmark(cfg, tmp_path / "run2")  # every case resumes from the state folder: no world is built
    assert CALLS == []
    assert (tmp_path / "run2" / "gap_benchmark.md").read_text() == md.read_text()
    with h5py.File(next((tmp_path / "cache" / "world").glob("fake_none.h5")), "r") as h5:
        assert "truth" not in h5.attrs  # the diagnosed data never carry the truth


def test_candidate_scan_credits_the_worlds_own_change(tmp_path, radar, short_chain, request):
    """benchmarks/candidate_scan.py on a fake antenna-pattern case: the world's own variant closes the
    whole gap and its change is the world's (r = 1), a weaker one part of it; the probe effect
    palm_lobe is there to be scanned and at zero strength changes nothing."""
    import benchmarks.probe_effects
    from benchmarks.candidate_scan import scan

    # the probe effect leaves the registry after this test: a diagnosis with candidates=None scores
    # every registered effect, and no other test expects it
    request.addfinalizer(lambda: REGISTRY.pop(benchmarks.probe_effects.PalmLobe.name, None))
    case = case_world({}, next(c for c in cases(["antenna_pattern"])))
    none = case_world({}, Case(CONTROL_NOTHING, (), "none"))
    path = fake_world(case, radar, short_chain, tmp_path)
    clean = fake_world(none, radar, short_chain, tmp_path, window_starts_s=window_starts(path).tolist())
    variants = [{"antenna_pattern": {"q": 6.0}}, {"antenna_pattern": {"q": 2.0}}, {"palm_lobe": {"rcs0_m2": 0.0}}]
    on_case = scan(path, clean, {}, variants, exponent=1.0, halves=3)
    # to the engine's re-weighting of the antenna pattern between skeleton steps (second order)
    assert on_case[0]["gap_closed"] == pytest.approx(1.0, abs=1e-4) and on_case[0]["r"] == pytest.approx(1.0, abs=1e-4)
    assert 0.0 < on_case[1]["gap_closed"] < 1.0 and on_case[1]["r"] > 0.5
    # each split seed's evaluation half: the whole gap closed there too, the weaker variant part of it
    assert on_case[0]["on_halves"] == pytest.approx([1.0] * 3, abs=1e-4)
    assert len(on_case[1]["on_halves"]) == 3 and all(0.0 < g < 1.0 for g in on_case[1]["on_halves"])
    assert on_case[2]["gap_closed"] == pytest.approx(0.0, abs=1e-9)
    # the fake effect-free world is the simulator itself: no gap to close at exponent 1 (nan, not a
    # division by zero); at 0.5 a generic gap that a candidate may close, and no world change to match
    clean_own = fake_world(none, radar, short_chain, tmp_path)
    assert np.isnan(scan(clean_own, None, {}, variants[:1], exponent=1.0)[0]["gap_closed"])
    on_clean = scan(clean_own, None, {}, variants[:1], exponent=0.5)
    assert np.isfinite(on_clean[0]["gap_closed"]) and "r" not in on_clean[0]



def test_benchmark_resumes_finished_cases_and_redoes_only_the_missing_one(tmp_path, radar, short_chain):
    """The fast version of the run above: one candidate, the paper's RCS only. A second run resumes
    every case from the state folder (no world built, the same results); with one case's state
    removed, only that case's world and the effect-free world it is compared with are built again."""
    cfg = OmegaConf.create({
        "task_name": "gap_benchmark", "progress": False,
        "radar": {"_target_": "handradar.radar.config.RadarConfig.from_cfg_text", "text": radar.to_cfg(), "source": "test"},
        "chain": {"_target_": "handradar.radar.chain.ChainConfig", "n_columns": short_chain.n_columns},
        "paths": {"cache_dir": str(tmp_path / "cache")},
        "sim": {"_target_": "handradar.sim.simulator.Simulator", "_partial_": True, "effects": [], "effect_params": {}},
        "diagnose": {"candidates": ["antenna_pattern"], "radarweightnet": False, "n_boot": 100, "greedy_max": 1,
                     "rcs_exponents": [1.0]},
        "world": {"seed": 7},
        "benchmark": {"builder": "tests.gap.test_benchmark.fake_world", "cases": ["antenna_pattern", "nothing"],
                      "world": {"subjects": 1}, "state_dir": str(tmp_path / "state")}})
    CALLS.clear()
    run_benchmark(cfg, tmp_path / "run")
    first = json.loads((tmp_path / "run" / "benchmark.json").read_text())
    by = {r["case"]: r for r in first["results"]}
    assert (by["antenna_pattern"]["cause"], by["nothing"]["cause"]) == ("antenna_pattern", "none")
    assert len(CALLS) == 4  # 2 cases + the effect-free world with its own windows and with antenna_pattern's
    states = sorted(p.name.split("-")[0] for p in (tmp_path / "state").glob("*.json"))
    assert states == ["antenna_pattern", "nothing"]
    CALLS.clear()
    run_benchmark(cfg, tmp_path / "run2")
    assert CALLS == []
    again = json.loads((tmp_path / "run2" / "benchmark.json").read_text())
    assert again["results"] == first["results"] and again["scores"] == first["scores"]
    assert not (tmp_path / "run2" / "cases").exists()  # nothing was diagnosed again
    next((tmp_path / "state").glob("antenna_pattern-*.json")).unlink()
    run_benchmark(cfg, tmp_path / "run3")
    built = [sorted(n for n, e in c["effects"].items() if e.get("enabled") and n in EFFECT_NAMES) for c in CALLS]
    assert built == [["antenna_pattern"], [], []] and [c["window_starts_s"] is None for c in CALLS] == [True, True, False]
    third = json.loads((tmp_path / "run3" / "benchmark.json").read_text())
    assert [r["cause"] for r in third["results"]] == [r["cause"] for r in first["results"]]
    assert (tmp_path / "run3" / "cases" / "antenna_pattern" / "gap_report.json").is_file()
    assert not (tmp_path / "run3" / "cases" / "nothing").exists()


def test_several_effects_withheld_at_once_are_one_case_judged_by_what_is_kept():
    from handradar.gap.benchmark import kept_scores
    (case,) = cases(["tracking_jitter+forearm+multipath"])
    assert case.on == ("tracking_jitter", "forearm", "multipath") and case.truth == case.name
    world = case_world({}, case)
    assert {k for k, v in world["effects"].items() if v["enabled"]} == {"tracking_jitter", "forearm", "multipath"}
    for bad in ("forearm+forearm", "forearm+nothing", "forearm+warp"):
        with pytest.raises(ValueError, match="joined by"):
            cases([bad])
    assert kept_scores(["forearm", "noise"], case.truth) == {"kept_precision": 0.5, "kept_recall": pytest.approx(1 / 3)}
    assert kept_scores([], case.truth) == {"kept_precision": None, "kept_recall": 0.0}
    r = {"truth": case.truth, "cause": "forearm", "top_candidate": "forearm", "after_effects": ["forearm"]}
    assert found(r) and not wrong_cause(r)
    assert wrong_cause({**r, "cause": "noise"}) and not found({**r, "cause": "noise", "top_candidate": "noise"})
    res = [{**r, "case": case.name, "true_gap_closed": None, "after_gap_closed": 0.2, **kept_scores(["forearm"], case.truth),
            "reference_gap_closed": 0.3},
           {"case": "nothing", "truth": "none", "cause": "none", "true_gap_closed": None, "after_gap_closed": 0.0}]
    s = score(res)
    assert s["effects_total"] == 0 and s["controls_total"] == 1  # the several-effect case is scored apart
    # its MLflow metric names are valid ones (letters, digits, _-. :/), where the case's own name is not
    from handradar.gap.benchmark import case_metrics

    report = {"baseline": {"ssim": 0.9, "mse": 0.01}, "after": {"ssim": 0.92, "gap_closed": 0.2},
              "candidates": [{"effect": "forearm", "gap_closed": 0.1, "ci95": [0.05, 0.15]}]}
    names = list(case_metrics(case.name, report))
    assert "bench/tracking_jitter-forearm-multipath/after_gap_closed" in names
    assert all(re.fullmatch(r"[A-Za-z0-9_\-. :/]+", n) for n in names)
    assert s["several"] == [{"case": case.name, "after_effects": ["forearm"], "kept_precision": 1.0,
                             "kept_recall": pytest.approx(1 / 3), "after_gap_closed": 0.2, "reference_gap_closed": 0.3}]


def _folder_manifest(tmp_path, text: str):
    path = tmp_path / "held_back" / "folders.yaml"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


@pytest.mark.parametrize("text, problem", [
    ("folders: []\n", "expected a mapping 'folders"),
    ("folders:\n  a: {root: a}\n", "folder 'a': expected {root: DIR, truth: EFFECT}"),
    ("folders:\n  a: {root: missing, truth: palm}\n", "folder 'a': .*missing is not a folder"),
    ("folders:\n  a: {root: ., truth: palm+palm}\n", "truth 'palm\\+palm'"),
    ("folders:\n  a: {root: ., truth: glare}\n", "truth 'glare'"),
    ("also_present: [glare]\nfolders:\n  a: {root: ., truth: none}\n", "also_present: glare not in"),
    ("folders: {a: [\n", "not readable as YAML: expected the node content"),
])
def test_a_bad_folder_manifest_is_one_line_naming_the_manifest_and_the_problem(tmp_path, text, problem):
    path = _folder_manifest(tmp_path, text)
    with pytest.raises(FormatError, match=problem) as err:
        FolderCases.load(path)
    assert str(err.value).startswith(str(path)) and "\n" not in str(err.value)
    with pytest.raises(FormatError, match="manifest not found"):
        FolderCases.load(tmp_path / "nowhere.yaml")


def test_folders_with_known_answers_are_ingested_diagnosed_judged_and_resumed(tmp_path, radar, short_chain):
    """benchmark.folders: two folders of the same 8 recordings of the independent writer, whose one point
    reflector at the hand centre is what the palm effect adds (tests/gap/test_cli.py): listed with truth palm
    the answer is found; listed with truth noise, palm is a wrong cause, unless the manifest says every
    folder carries palm. Two more folders, with receiver noise, against the simulator's sign convention
    are named with their fixes: Doppler-mirrored (doppler_flip) and I/Q-swapped (iq_swap, from the range
    figure ingest carries into the dataset: the swapped rows' Doppler r is leakage and noise). A second
    run resumes every case: nothing is ingested or diagnosed again."""
    for folder in ("a", "b", "mirrored", "swapped"):
        for i in range(8):
            write_recording(tmp_path / "held_back" / folder / f"rec{i}",
                            Scene(gesture=("grasp", "circle")[i % 2], subject=f"s{i % 3}",
                                  velocity_m_s=-0.08 - 0.02 * i, repetition=i, mirror_doppler=folder == "mirrored",
                                  swap_iq=folder == "swapped", noise_counts=30.0 if folder in ("mirrored", "swapped")
                                  else 0.0))
    manifest = _folder_manifest(tmp_path, "folders:\n  palm_case: {root: a, truth: palm}\n"
                                          f"  noise_case: {{root: {tmp_path / 'held_back' / 'b'}, truth: noise}}\n"
                                          "  flipped: {root: mirrored, truth: palm}\n"
                                          "  swapped: {root: swapped, truth: palm}\n")
    cfg = OmegaConf.create({
        "task_name": "gap_benchmark", "progress": False, "skeleton_rate_hz": 100.0,
        "radar": {"_target_": "handradar.radar.config.RadarConfig.from_cfg_text", "text": radar.to_cfg(), "source": "test"},
        "chain": {"_target_": "handradar.radar.chain.ChainConfig", "n_columns": short_chain.n_columns},
        "paths": {"cache_dir": str(tmp_path / "cache")},
        "sim": {"_target_": "handradar.sim.simulator.Simulator", "_partial_": True, "effects": [], "effect_params": {}},
        "diagnose": {"candidates": ["palm"], "radarweightnet": False, "n_boot": 200, "greedy_max": 1, "folds": 1,
                     "fit_rows": None, "rcs_exponents": [1.0]},
        "benchmark": {"folders": str(manifest), "cases": ["never_built"], "state_dir": str(tmp_path / "state"),
                      "record_dir": str(tmp_path / "results")}})
    record = validate_record(json.loads(run_benchmark(cfg, tmp_path / "run").read_text()), "record")
    by = {c["case"]: c for c in record["cases"]}
    assert record["world"] == "folders-held_back" and record["world_version"] == "recordings" and record["size"] == 8
    assert "data_source" not in record  # a hand-written manifest does not say how its folders were made
    assert (tmp_path / "results" / "folders-held_back_8.json").is_file()
    assert by["palm_case"]["cause"] == by["noise_case"]["cause"] == "palm"
    assert found(by["palm_case"]) and not wrong_cause(by["palm_case"]) and wrong_cause(by["noise_case"])
    assert len(list((tmp_path / "cache" / "datasets").glob("recordings-*.h5"))) == 4  # each folder ingested
    # a folder against the simulator's sign convention is named with its fix
    assert [by[c]["convention_fix"] for c in ("palm_case", "noise_case", "flipped", "swapped")] == \
        [None, None, "doppler_flip", "iq_swap"]
    md = (tmp_path / "run" / "gap_benchmark.md").read_text()
    assert f"listed in {manifest}" in md and "| noise_case | noise | palm | no |" in md
    assert ("sign convention** (re-ingest with the fix; the verdict is not the simulator's): "
            "flipped (doppler_flip=true), swapped (iq_swap=true).") in md
    assert "signature_mean" not in by["palm_case"]  # no effect-free twin: no truth side
    for h5 in (tmp_path / "cache" / "datasets").glob("recordings-*.h5"):
        h5.unlink()
    manifest.write_text("also_present: [palm]\n" + manifest.read_text())
    again = json.loads(run_benchmark(cfg, tmp_path / "run2").read_text())
    assert not (tmp_path / "run2" / "cases").exists() and not list((tmp_path / "cache" / "datasets").glob("*.h5"))
    assert [c["cause"] for c in again["cases"][:2]] == ["palm", "palm"] and not wrong_cause(again["cases"][1])
    assert [c["convention_fix"] for c in again["cases"][2:]] == ["doppler_flip", "iq_swap"]


def test_case_folders_writes_the_benchmarks_case_worlds_and_a_manifest_the_folder_benchmark_reads(tmp_path):
    """benchmarks/case_folders.py: each case's recordings are that case's world (its truth in meta.json:
    the case's own effect on, every other vocabulary effect off) and the manifest names each folder's answer."""
    from benchmarks.case_folders import main

    manifest = main(tmp_path / "cases", [
        "benchmark.size=null", "benchmark.cases=[palm,nothing]", f"paths.cache_dir={tmp_path / 'cache'}",
        "+benchmark.world={subjects: 1, repetitions: 1, gestures: [grasp], angles_deg: [0.0]}"])
    folders = FolderCases.load(manifest)
    assert {c.name: c.truth for c in folders.cases} == {"palm": "palm", "nothing": "none"} and folders.present == []
    # the record names the folders by the command that wrote them, without this machine's paths
    assert folders.source == ("python -m benchmarks.case_folders DIR benchmark.size=null 'benchmark.cases=[palm,nothing]' "
                              "'+benchmark.world={subjects: 1, repetitions: 1, gestures: [grasp], angles_deg: [0.0]}'")
    for case, on in (("palm", {"palm"}), ("nothing", set())):
        metas = [json.loads(p.read_text()) for p in (tmp_path / "cases" / case).glob("*/meta.json")]
        assert len(metas) == 1 and metas[0]["gesture"] == "grasp"
        effects = metas[0]["truth"]["effects"]
        assert {n for n in EFFECT_NAMES if effects[n]["enabled"]} == on
