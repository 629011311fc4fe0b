"""Figures of the gap diagnosis (PNG, matplotlib's Agg backend), and of the withheld-effect benchmark.

    diagnosis_figures(diagnosis, radar, chain, out_dir) -> {name: Path}
        residual.png     signed mean residual over Doppler (velocity axis) and time, and its map
        factors.png      evaluation SSIM per level of each factor
        bones.png        reflection points: excess (-) / missing (+) energy per bone
        candidates.png   gap_closed with 95 % CI per candidate (+ RadarWeightNet), cause marked
        signatures.png   per candidate: baseline residual vs the change it makes (Doppler profiles)
        examples.png     measured / baseline / after (/ RadarWeightNet) spectrograms of evaluation rows
    confusion_figure(matrix, true_labels, predicted_labels, path) -> Path   (benchmark)
All files are written atomically.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from handradar.atomic import atomic_path  # noqa: E402
from handradar.metrics import per_example_ssim
from handradar.radar.chain import ChainConfig, velocity_axis_m_s  # noqa: E402
from handradar.radar.config import RadarConfig  # noqa: E402


def _save(fig, path: Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path


def _column_times(radar: RadarConfig, chain: ChainConfig) -> np.ndarray:
    cpf = chain.columns_per_frame(radar)
    return (np.arange(chain.n_columns) + 0.5) * radar.frame_period_s / cpf


def residual_figure(measured: np.ndarray, baseline: np.ndarray, radar: RadarConfig, chain: ChainConfig,
                    path: Path) -> Path:
    r = measured - baseline
    vel = velocity_axis_m_s(radar, chain)
    t = _column_times(radar, chain)
    fig, ax = plt.subplots(1, 3, figsize=(13, 3.4))
    ax[0].axhline(0, color="0.6", lw=0.8)
    ax[0].plot(vel, r.mean(axis=(0, 2)), color="C3")
    ax[0].set(xlabel="radial velocity (m/s, + approaching)", ylabel="mean residual", title="over Doppler")
    ax[1].axhline(0, color="0.6", lw=0.8)
    ax[1].plot(t, r.mean(axis=(0, 1)), color="C3")
    ax[1].set(xlabel="time in window (s)", title="over time")
    lim = float(np.abs(r.mean(0)).max()) or 1.0
    im = ax[2].imshow(r.mean(0), aspect="auto", origin="lower", cmap="RdBu_r", vmin=-lim, vmax=lim,
                      extent=(t[0], t[-1], vel[0], vel[-1]))
    ax[2].set(xlabel="time (s)", ylabel="velocity (m/s)", title="measured - simulated")
    fig.colorbar(im, ax=ax[2])
    fig.suptitle("Where: signed mean residual on the evaluation split (+ = energy the simulator misses)")
    return _save(fig, path)


def factor_figure(by_factor: dict, baseline_ssim: float, path: Path) -> Path:
    factors = [f for f, levels in by_factor.items() if levels]
    fig, axes = plt.subplots(1, max(len(factors), 1), figsize=(3.2 * max(len(factors), 1), 3.2), squeeze=False)
    for ax, f in zip(axes[0], factors):
        levels = by_factor[f]
        names = list(levels)
        ax.bar(range(len(names)), [levels[n]["ssim"] for n in names], color="C0")
        ax.axhline(baseline_ssim, color="C3", lw=1, ls="--")
        ax.set_xticks(range(len(names)), [f"{n}\n({levels[n]['n']})" for n in names], rotation=60, fontsize=7)
        lo = min(levels[n]["ssim"] for n in names)
        ax.set_ylim(max(0.0, lo - 0.1), 1.0)
        ax.set_title(f, fontsize=9)
    axes[0][0].set_ylabel("SSIM (baseline simulator)")
    fig.suptitle("Where: SSIM by factor (dashed: mean; counts in brackets)")
    return _save(fig, path)


def bone_figure(points: dict[str, float], path: Path) -> Path:
    names = list(points)
    vals = np.array([points[n] for n in names])
    fig, ax = plt.subplots(figsize=(6, 0.25 * len(names) + 1.2))
    ax.barh(range(len(names)), vals, color=np.where(vals > 0, "C3", "C0"))
    ax.axvline(0, color="0.3", lw=0.8)
    ax.set_yticks(range(len(names)), names, fontsize=7)
    ax.invert_yaxis()
    ax.set_xlabel("share-weighted mean residual (+ missing energy, - excess)")
    ax.set_title("Where: reflection points")
    return _save(fig, path)


def candidate_figure(report: dict, path: Path) -> Path:
    cands = report["candidates"]
    rows = [(c["effect"], c["gap_closed"], c["ci95"], c["effect"] == report["cause"], c.get("significant", False))
            for c in cands]
    rwn = report.get("radarweightnet")
    if rwn:
        rows.append(("RadarWeightNet", rwn["gap_closed"], rwn["ci95"], False, rwn["ci95"][0] > 0))
    fig, ax = plt.subplots(figsize=(7, 0.38 * len(rows) + 1.3))
    for i, (name, g, ci, is_cause, sig) in enumerate(rows):
        color = "C3" if is_cause else ("C1" if sig else "0.6")
        ax.errorbar(g, i, xerr=[[g - ci[0]], [ci[1] - g]], fmt="o", color=color, capsize=3,
                    mfc="white" if name == "RadarWeightNet" else color)
    ax.axvline(0, color="0.3", lw=0.8)
    ax.set_yticks(range(len(rows)), [r[0] for r in rows])
    ax.invert_yaxis()
    ax.set_xlabel("gap_closed on the evaluation split (95 % paired-bootstrap CI)")
    ax.set_title(f"Which: cause = {report['cause']} (red; orange: significant)")
    return _save(fig, path)


def signature_figure(measured: np.ndarray, baseline: np.ndarray, candidates: dict[str, np.ndarray], report: dict,
                     radar: RadarConfig, chain: ChainConfig, path: Path) -> Path:
    vel = velocity_axis_m_s(radar, chain)
    res = (measured - baseline).mean(axis=(0, 2))
    corr = {c["effect"]: c["signature_correlation"] for c in report["candidates"]}
    names = [c["effect"] for c in report["candidates"] if c["effect"] in candidates]
    n = max(len(names), 1)
    cols = min(4, n)
    nrows = (n + cols - 1) // cols
    fig, axes = plt.subplots(nrows, cols, figsize=(3.3 * cols, 2.5 * nrows), squeeze=False, sharex=True)
    for ax in axes.flat[len(names):]:
        ax.axis("off")
    for ax, name in zip(axes.flat, names):
        change = (candidates[name] - baseline).mean(axis=(0, 2))
        ax.axhline(0, color="0.7", lw=0.6)
        ax.plot(vel, res, color="0.3", lw=1, label="residual")
        ax.plot(vel, change, color="C3", lw=1, label="change")
        ax.set_title(f"{name} (r = {corr.get(name, 0.0):+.2f})", fontsize=8)
        ax.tick_params(labelsize=6)
    axes.flat[0].legend(fontsize=6)
    fig.suptitle("Which: residual signature (measured - baseline) vs each candidate's change, over Doppler;"
                 " r: correlation of the mean maps", fontsize=9)
    return _save(fig, path)


def example_figure(measured: np.ndarray, panels: dict[str, np.ndarray], ssim: dict[str, np.ndarray], n: int,
                   path: Path) -> Path:
    """n evaluation rows (the worst baseline SSIM first... spread over the range): measured, then each panel."""
    order = np.argsort(ssim[next(iter(panels))])
    pick = order[np.linspace(0, len(order) - 1, min(n, len(order))).round().astype(int)]
    cols = 1 + len(panels)
    fig, axes = plt.subplots(len(pick), cols, figsize=(2.0 * cols, 2.1 * len(pick)), squeeze=False)
    for i, row in enumerate(pick):
        axes[i][0].imshow(measured[row], aspect="auto", origin="lower", vmin=0, vmax=1, cmap="viridis")
        axes[i][0].set_title("measured", fontsize=8)
        for j, (name, spec) in enumerate(panels.items(), start=1):
            axes[i][j].imshow(spec[row], aspect="auto", origin="lower", vmin=0, vmax=1, cmap="viridis")
            axes[i][j].set_title(f"{name}\nSSIM {ssim[name][row]:.3f}", fontsize=8)
        for ax in axes[i]:
            ax.set_xticks([])
            ax.set_yticks([])
    fig.suptitle("Before / after on evaluation rows (Doppler up, time right)", fontsize=9)
    return _save(fig, path)


def diagnosis_figures(diagnosis, radar: RadarConfig, chain: ChainConfig, out_dir: str | Path) -> dict[str, Path]:
    out = Path(out_dir)
    rep = diagnosis.report
    figs = {"residual": residual_figure(diagnosis.measured, diagnosis.baseline, radar, chain, out / "residual.png"),
            "factors": factor_figure(rep["where"]["by_factor"], rep["baseline"]["ssim"], out / "factors.png"),
            "candidates": candidate_figure(rep, out / "candidates.png")}
    if rep["where"]["reflection_points"]:
        figs["bones"] = bone_figure(rep["where"]["reflection_points"], out / "bones.png")
    if diagnosis.candidates:
        figs["signatures"] = signature_figure(diagnosis.measured, diagnosis.baseline, diagnosis.candidates, rep,
                                              radar, chain, out / "signatures.png")
    # examples from the rows every panel covers (RadarWeightNet's readout: one fold's rows with cross-fitting)
    rows = diagnosis.rwn_rows if diagnosis.rwn is not None else np.arange(len(diagnosis.measured))
    panels = {"baseline": diagnosis.baseline[rows]}
    if rep["after"]["effects"] and diagnosis.after is not None:
        panels["after: " + "+".join(rep["after"]["effects"])] = diagnosis.after[rows]
    if diagnosis.rwn is not None:
        panels["RadarWeightNet"] = diagnosis.rwn
    measured = diagnosis.measured[rows]
    ssim = {k: per_example_ssim(measured, v) for k, v in panels.items()}
    figs["examples"] = example_figure(measured, panels, ssim, rep.get("settings", {}).get("n_examples", 4),
                                      out / "examples.png")
    return figs


def confusion_figure(matrix: np.ndarray, true_labels: list[str], predicted_labels: list[str], path: str | Path,
                     title: str = "") -> Path:
    m = np.asarray(matrix)
    fig, ax = plt.subplots(figsize=(0.65 * len(predicted_labels) + 2.5, 0.5 * len(true_labels) + 1.8))
    ax.imshow(m, cmap="Blues", vmin=0, vmax=max(1, m.max()))
    for i in range(m.shape[0]):
        for j in range(m.shape[1]):
            if m[i, j]:
                ax.text(j, i, str(int(m[i, j])), ha="center", va="center",
                        color="white" if m[i, j] > m.max() / 2 else "black")
    ax.set_xticks(range(len(predicted_labels)), predicted_labels, rotation=45, ha="right")
    ax.set_yticks(range(len(true_labels)), true_labels)
    ax.set_xlabel("attributed cause")
    ax.set_ylabel("withheld effect (world)")
    ax.set_title(title or "Gap benchmark: withheld effect x attributed cause")
    return _save(fig, path)
