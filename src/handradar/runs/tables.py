"""Result tables in the paper's layout, from job records (MLflow runs or one finished job).

- Table I (synthesis): one row per evaluation (held-out rows and the four generalisation
  shifts), columns SSIM and MSE of the modelling-only and the RadarWeightNet-enhanced simulator.
- Table II (few-shot): one row per real-data fraction and test protocol (``*``: the fixed test split
  of the complete dataset), one column per variant (radar only, + model-based synthetic,
  + RadarWeightNet-enhanced synthetic, + CGAN; synthetic only, enhanced and model-based: train on
  synthetic, test on real; the pool's real rows, their upper reference).
- Table III (pre-training): one row per (classes, fraction, simulator), columns trained from scratch,
  pre-trained on synthetic spectrograms of an external skeleton dataset, and their difference per seed.
- Table IV (out of distribution): one row per OOD split, the variant columns.

Cells are ``mean ± std`` of the accuracy over the records of a row (seeds), with the count.
A record is ``{"params": flat config (dotted keys -> str), "metrics": {name: float}}``, optionally with
``"provenance"`` (:func:`provenance`: command, commit, seed, machine, data source): each row then lists
the runs behind it (:meth:`Table.provenance_markdown`; ``make tables`` writes both to docs/results.md,
reading the finished MLflow runs with :func:`load_records`).

A published command names no path of the machine that ran it (:func:`published_command`): where outputs
and caches went is left out, and a data folder reads ``DIR``, said how to make by the command that wrote
it (:func:`published`). A row with a run from a working tree with uncommitted changes is marked
(:data:`DIRTY_MARK`).
"""

from __future__ import annotations

import csv
import io
import logging
import math
import re
import shlex
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path, PurePath

import scipy.stats
import yaml

from handradar.provenance import REPO_ROOT, commit_of
from handradar.runs.mlflow import TAG_PREFIX, Tracker, store_exists
from handradar.vocab import MEASURED_VARIANTS

log = logging.getLogger(__name__)

VARIANT_COLUMNS = (
    ("radar_only", "Radar only"),
    ("model_synth", "+ model-based synthetic"),
    ("enhanced_synth", "+ RadarWeightNet synthetic"),
    ("cgan", "+ CGAN"),
    ("synth_only", "synthetic only (RadarWeightNet)"),
    ("model_synth_only", "synthetic only (model-based)"),
    ("radar_pool", "radar, whole pool"),
)
MEASURED_JOB = "handradar.tasks.measured.run_measured"
OOD_LABELS = {
    "angle": "angle (0° → ±30°)",
    "subject": "subject (unseen subjects)",
    "hands": "hands (single → double)",
    "occlusion": "occlusion (without → with)",
}
SYNTH_ROWS = (("", "held-out"), ("_hands", "single → double hands"), ("_occlusion", "non-occluded → occluded"),
              ("_angle", "0° → ±30°"), ("_subject", "unseen subjects"))
SYNTH_COLUMNS = (("ssim_model", "SSIM modelling"), ("ssim_enhanced", "SSIM + RadarWeightNet"),
                 ("mse_model", "MSE modelling"), ("mse_enhanced", "MSE + RadarWeightNet"))
SYNTH_JOB = "handradar.synthesis.job.run_synth_fit"
PRETRAIN_METRIC = re.compile(r"^test/acc_(scratch|pretrained)_(\d+)c_(\d+)pct$")
DEFAULT_TRACKING_URI = f"sqlite:///{REPO_ROOT / 'logs' / 'mlflow' / 'mlflow.db'}"  # conf/logger/mlflow.yaml's store
# overrides that only say where outputs and caches go change no result (the job hash leaves paths out)
WHERE_KEYS = ("paths.", "hydra.run.", "hydra.sweep.")
LOCAL = "DIR"  # a path of the machine that ran a job, as a published command shows it
DIRTY_MARK = "†"
DIRTY_NOTE = (f"{DIRTY_MARK}: a run behind it was made from a working tree with uncommitted changes (its commit reads "
              "`.dirty`), so that commit alone does not reproduce it.")


@dataclass
class Table:
    name: str
    title: str
    columns: list[str]
    rows: dict[str, dict[str, list[float]]] = field(default_factory=dict)  # row -> column -> values
    order: dict[str, tuple] = field(default_factory=dict)  # row -> sort key
    sources: dict[str, list[dict]] = field(default_factory=dict)  # row -> provenance of the runs behind it
    signed: tuple[str, ...] = ()  # columns of differences: their cells show the sign
    interval: bool = False        # cells show the mean and its 95 % t-interval over the values, not the spread

    def add(self, row: str, column: str, value: float, sort_key: tuple = (), source: Mapping | None = None) -> None:
        self.rows.setdefault(row, {}).setdefault(column, []).append(float(value))
        self.order.setdefault(row, sort_key)
        if source is not None and dict(source) not in self.sources.setdefault(row, []):
            self.sources[row].append(dict(source))

    def provenance_markdown(self) -> str:
        """One line per row: the command that reproduces it (its seeds as one multirun), commit and machine."""
        lines = []
        for r in self.sorted_rows():
            runs = group_runs(self.sources.get(r, []))
            text = "; ".join(f"{published(g['command'], g['data_source'])} at `{g['commit']}`, "
                             f"seed{'s' if len(g['seeds']) > 1 else ''} "
                             f"{', '.join(g['seeds'])}, {g['machine']}" + (" (command reconstructed from the run's tags)"
                                                                           if g["reconstructed"] else "")
                             for g in runs)
            lines.append((r, text or "no provenance recorded"))
        if len(lines) > 1 and len({text for _, text in lines}) == 1:  # one job behind every row: say it once
            return f"- every row: {lines[0][1]}"
        return "\n".join(f"- {r}: {text}" for r, text in lines)

    def sorted_rows(self) -> list[str]:
        return sorted(self.rows, key=lambda r: (self.order[r], r))

    def dirty_rows(self) -> list[str]:
        """Rows with a run from a working tree with uncommitted changes."""
        return [r for r in self.sorted_rows() if any(dirty(src["commit"]) for src in self.sources.get(r, []))]

    def markdown(self) -> str:
        """The table; a row from a dirty tree is marked (:data:`DIRTY_MARK`), with the note under the table."""
        lines = [f"**{self.title}**", "", "| | " + " | ".join(self.columns) + " |",
                 "|---|" + "---|" * len(self.columns)]
        marked = self.dirty_rows()
        for r in self.sorted_rows():
            lines.append(f"| {r}{' ' + DIRTY_MARK if r in marked else ''} | "
                         + " | ".join((mean_ci if self.interval else mean_std)(self.rows[r].get(c, []),
                                                                               signed=c in self.signed)
                                      for c in self.columns) + " |")
        return "\n".join(lines + (["", DIRTY_NOTE] if marked else []))

    def csv(self) -> str:
        buf = io.StringIO()
        w = csv.writer(buf)
        w.writerow(["row", *[f"{c} {s}" for c in self.columns for s in ("mean", "std", "n")]])
        for r in self.sorted_rows():
            cells = []
            for c in self.columns:
                m, s, n = stats(self.rows[r].get(c, []))
                cells += ["" if n == 0 else f"{m:.4f}", "" if n < 2 else f"{s:.4f}", n]
            w.writerow([r, *cells])
        return buf.getvalue()


def stats(values: Sequence[float]) -> tuple[float, float, int]:
    """Mean, sample standard deviation (ddof 1; nan below 2 values) and count."""
    n = len(values)
    if n == 0:
        return math.nan, math.nan, 0
    m = sum(values) / n
    s = math.sqrt(sum((v - m) ** 2 for v in values) / (n - 1)) if n > 1 else math.nan
    return m, s, n


def provenance(tags: Mapping[str, str], params: Mapping[str, str], overrides: Sequence[str] | None = None,
               script: str = "train.py") -> dict:
    """Where a run's figures come from: ``command`` (its ``handradar.command`` tag, else ``python SCRIPT``
    with the job's Hydra ``overrides``, else rebuilt from its preset and seed: ``reconstructed``), ``commit``,
    ``seed``, ``machine`` ("not recorded" for runs logged before the tag existed) and ``data_source`` (its
    ``handradar.data_source`` tag: the command that wrote its data folder, None where not recorded)."""
    seed = str(tags.get("handradar.seed", params.get("seed", "?")))
    command, rebuilt = tags.get("handradar.command"), False
    if not command and overrides is not None:
        command = " ".join(["python", script, *map(shlex.quote, overrides)])
    if not command:
        command, rebuilt = f"python {script} +experiment={tags.get('handradar.preset', '?')} seed={seed}", True
    return {"command": command, "commit": commit_of(tags.get("handradar.code_version", "")), "seed": seed,
            "machine": tags.get("handradar.machine", "machine not recorded"), "reconstructed": rebuilt,
            "data_source": tags.get("handradar.data_source")}


def group_runs(sources: Sequence[Mapping]) -> list[dict]:
    """Runs that differ only in their seed, as one multirun command (``-m ... seed=1,2,3``), as published
    (:func:`published_command`)."""
    groups: dict[tuple, dict] = {}
    for src in sources:
        base = [w for w in shlex.split(published_command(src["command"])) if not w.startswith("seed=")]
        key = (tuple(base), src["commit"], src["machine"], src.get("reconstructed", False), src.get("data_source"))
        g = groups.setdefault(key, {"base": base, "commit": src["commit"], "machine": src["machine"], "seeds": [],
                                    "reconstructed": src.get("reconstructed", False),
                                    "data_source": src.get("data_source")})
        if src["seed"] not in g["seeds"]:
            g["seeds"].append(src["seed"])
    out = []
    for g in groups.values():
        g["seeds"].sort(key=lambda x: (len(x), x))
        base = g.pop("base")
        if len(g["seeds"]) > 1 and len(base) >= 2 and base[0] == "python" and "-m" not in base:
            base = [*base[:2], "-m", *base[2:]]
        g["command"] = " ".join(map(shlex.quote, [*base, f"seed={','.join(g['seeds'])}"]))
        out.append(g)
    return out


def _local(word: str) -> str:
    """A path of the machine that ran a job as :data:`LOCAL` (a file keeps its name: ``DIR/folders.yaml``);
    any other word as it is."""
    if not word.startswith(("/", "~")):
        return word
    path = PurePath(word)
    return f"{LOCAL}/{path.name}" if path.suffix else LOCAL


def published_command(command: str, skip: Iterable[str] = ()) -> str:
    """``command`` as a published record shows it: overrides of where outputs and caches go (``paths.*``, and
    the keys in ``skip``) left out, and every absolute path, an argument or an override's value, as ``DIR``."""
    words = []
    for word in shlex.split(command):
        key, eq, value = word.partition("=")
        name = key.lstrip("+~")
        if eq and (name.startswith(WHERE_KEYS) or name in skip):
            continue
        words.append(f"{key}={_local(value)}" if eq else _local(word))
    return " ".join(map(shlex.quote, words))


def published(command: str, data_source: str | None = None) -> str:
    """A command for a published record, in backticks (:func:`published_command`); where it names a folder
    as ``DIR``, what that folder holds: ``data_source``, the command that wrote it, or that it is not recorded."""
    shown = published_command(command)
    values = [w.partition("=")[2] or w for w in shlex.split(shown)]
    if not any(v == LOCAL or v.startswith(f"{LOCAL}/") for v in values):
        return f"`{shown}`"
    made = f"written by `{published_command(data_source)}`" if data_source else "its source not recorded"
    return f"`{shown}` ({LOCAL}: {made})"


def dirty(commit: str) -> bool:
    """Whether a commit (:func:`handradar.provenance.commit_of`) is of a working tree with uncommitted changes."""
    return commit.endswith(".dirty")


def results_markdown(tables: Sequence[Table], source: str) -> str:
    """docs/results.md: every table, and under it each row's runs (command, commit, seeds, machine)."""
    sections = [f"# handradar results\n\nGenerated by `make tables` from the finished MLflow runs in {source}; "
                "do not edit. Each cell is the mean ± standard deviation over seeds (n: how many). Under each table, "
                "the runs behind each row: the command that reproduces them, the commit, the seeds and the machine. "
                f"A command names its data folder `{LOCAL}` and says which command wrote it; where outputs and caches "
                "went is left out."]
    for t in tables:
        sections.append(t.markdown() + "\n\nRuns:\n\n" + t.provenance_markdown())
    if not tables:
        sections.append("(no finished train.py jobs found)")
    return "\n\n".join(sections) + "\n"


def fmt_number(x: float | None, digits: int = 3, signed: bool = False) -> str:
    """A number for a markdown table: ``digits`` decimals, with its sign when ``signed``; None as "-"."""
    if x is None:
        return "-"
    return f"{x:+.{digits}f}" if signed else f"{x:.{digits}f}"


def mean_std(values: Sequence[float], signed: bool = False) -> str:
    m, s, n = stats(values)
    if n == 0:
        return "–"
    mean = fmt_number(m, signed=signed)
    return mean if n == 1 else f"{mean} ± {s:.3f} (n={n})"


def mean_ci(values: Sequence[float], signed: bool = False) -> str:
    """The mean and its 95 % Student-t interval over ``values`` (paired differences over seeds), with their count."""
    m, s, n = stats(values)
    if n == 0:
        return "–"
    mean = fmt_number(m, signed=signed)
    if n == 1:
        return f"{mean} (n=1)"
    half = float(scipy.stats.t.ppf(0.975, n - 1)) * s / math.sqrt(n)
    return f"{mean} [{fmt_number(m - half, signed=signed)}, {fmt_number(m + half, signed=signed)}] (n={n})"


def _pct(fraction: str | float) -> str:
    return f"{float(fraction) * 100:g} %"


def synthesis_setting(p: Mapping[str, str], metrics: Mapping[str, float] | None = None) -> str:
    """How a job's synthetic rows were made, when not by the configured simulator as is: its rows
    must not be averaged with those of other settings (e.g. " [fitted: effects, 2 draws]"). A guarded
    RadarWeightNet is named only where the job trained on RadarWeightNet rows (``metrics``)."""
    parts = []
    if p.get("synth.fit_sim", "none") not in ("none", "None"):
        parts.append(f"fitted: {p['synth.fit_sim']}")
    if int(float(p.get("synth.samples_per_row", 1))) > 1:
        parts.append(f"{int(float(p['synth.samples_per_row']))} draws")
    elif any(k.startswith("synth.randomize.") for k in p):
        parts.append("randomised")
    rwn = any(f"test/acc_{v}" in (metrics or {}) for v in ("enhanced_synth", "synth_only"))
    if rwn and int(float(p.get("synth.rwn_folds", 0))) > 0:  # RadarWeightNet fitted with held-out rows (guarded)
        parts.append(f"RadarWeightNet guarded, {int(float(p['synth.rwn_folds']))} folds")
    return f" [{', '.join(parts)}]" if parts else ""


def data_setting(p: Mapping[str, str], tags: Mapping[str, str] | None = None) -> str:
    """Which data a job trained and tested on, when not the default reference world: rows of other data
    are never averaged with its (" {recordings: mine}", " {file: mine.h5}", " {world: heldout}"). A world
    is named by the job's ``handradar.world`` tag (its Hydra choice), else, for runs logged before the tag,
    by its seed (0: the default world)."""
    target = p.get("data.dataset._target_", "")
    if target.endswith("MeasuredDataset"):
        return f" {{measured: {PurePath(p.get('data.dataset.manifest', '?')).stem}}}"
    if target.endswith("RecordingsFolder"):
        return f" {{recordings: {PurePath(p.get('data.dataset.root', '?')).name}}}"
    if target.endswith("DatasetFile"):
        return f" {{file: {PurePath(p.get('data.dataset.path', '?')).name}}}"
    world = (tags or {}).get("handradar.world")
    if world is None:
        seed = p.get("data.dataset.world.seed", "0")
        world = "default" if seed in ("0", "None") else f"seed {seed}"
    return "" if world == "default" else f" {{world: {world}}}"


def build_tables(records: Iterable[Mapping]) -> list[Table]:
    """Tables I-IV from job records; a table without records is left out."""
    variant_cols = [label for _, label in VARIANT_COLUMNS]
    synth = Table("table1_synthesis", "Table I: simulated vs measured spectrograms (modelling only vs + RadarWeightNet)",
                  [label for _, label in SYNTH_COLUMNS])
    few = Table("table2_few_shot", "Table II: few-shot accuracy (* = fixed test split of the complete dataset)",
                variant_cols)
    pre = Table("table3_pretrain", "Table III: accuracy with and without pre-training on external synthetic data",
                ["from scratch", "pre-trained", "pre-trained minus scratch"], signed=("pre-trained minus scratch",))
    ood = Table("table4_ood", "Table IV: out-of-distribution accuracy", variant_cols)
    measured = Table("measured", "Measured radar: accuracy on each held-out test split, K real rows per class of the "
                                 "training users", list(MEASURED_VARIANTS.values()))
    synthetic = [label for v, label in MEASURED_VARIANTS.items() if v != "radar_only"]
    gain = Table("measured_gain", "Measured radar: each synthetic variant's gain over radar only, paired by seed "
                                  "(mean [95 % t-interval] over seeds)", synthetic, signed=tuple(synthetic), interval=True)
    seen: set[tuple] = set()  # (table, row, column, seed): records come latest first, the latest run counts
    records = list(records)
    setting_suffix = measured_settings(records)
    for rec in records:
        p, metrics = rec["params"], rec["metrics"]
        kind, where = p.get("split.kind", "few_shot"), data_setting(p, rec.get("tags"))
        if p.get("job") == SYNTH_JOB:
            for i, (suffix, row) in enumerate(SYNTH_ROWS):
                for key, label in SYNTH_COLUMNS:
                    value = metrics.get(f"test/{key}{suffix}")
                    if value is not None:
                        synth.add(row + where, label, value, (i, where), rec.get("provenance"))
            continue
        if p.get("job") == MEASURED_JOB:
            _add_measured(measured, gain, rec, where + setting_suffix.get(where, {}).get(p.get("measured.setting"), ""),
                          seen)
            continue
        if p.get("job") not in ("variants", "external_pretrain"):
            continue  # not a train.py job
        if p.get("job") == "external_pretrain":
            source, setting = p.get("pretrain.source", "external"), where + synthesis_setting(p)
            found: dict[tuple[str, str], dict[str, float]] = {}  # (classes, pct) -> init -> accuracy
            for name, value in metrics.items():
                m = PRETRAIN_METRIC.match(name)
                if m:
                    found.setdefault(m.group(2, 3), {})[m.group(1)] = value
            for (classes, pct), acc in found.items():
                row = f"{classes} classes, {pct} % ({source}){setting}"
                cell = (pre.name, row, p.get("seed"))
                if p.get("seed") is not None and cell in seen:
                    continue
                seen.add(cell)
                # the paired difference: both arms of one job share its fine-tune split
                values = {"from scratch": acc.get("scratch"), "pre-trained": acc.get("pretrained"),
                          "pre-trained minus scratch": (acc["pretrained"] - acc["scratch"]) if len(acc) == 2 else None}
                for column, value in values.items():
                    if value is not None:
                        pre.add(row, column, value, (-int(classes), int(pct), setting), rec.get("provenance"))
            continue
        if kind == "ood":
            ood_kind = p.get("split.ood", "?")
            row, table, key = OOD_LABELS.get(ood_kind, ood_kind), ood, (list(OOD_LABELS).index(ood_kind)
                                                                        if ood_kind in OOD_LABELS else 9,)
        elif p.get("split.per_class") not in (None, "None"):
            fixed = p.get("split.test", "remainder") == "fixed"
            n = int(float(p["split.per_class"]))
            row, table, key = f"{n} per class" + ("*" if fixed else ""), few, (fixed, -1.0, n)
        elif "split.fraction" in p:
            fixed = p.get("split.test", "remainder") == "fixed"
            row, table, key = _pct(p["split.fraction"]) + ("*" if fixed else ""), few, (fixed, float(p["split.fraction"]))
        else:
            continue
        setting = where + synthesis_setting(p, metrics)
        row, key = row + setting, (*key, setting)
        for variant, label in VARIANT_COLUMNS:
            value = metrics.get(f"test/acc_{variant}")
            cell = (table.name, row, label, p.get("seed"))
            if value is not None and (p.get("seed") is None or cell not in seen):
                seen.add(cell)
                table.add(row, label, value, key, rec.get("provenance"))
    return [t for t in (synth, few, pre, ood, measured, gain) if t.rows]


def measured_settings(records: Sequence[Mapping]) -> dict[str, dict[str, str]]:
    """Per measured dataset (its :func:`data_setting`), each job setting's row suffix: "" for the setting most of its
    runs share (the latest of equals), " [setting <hash>]" for every other, so that no row mixes settings
    (``measured.setting``: the job's config hash without its seed and K)."""
    counts: dict[str, dict[str, int]] = {}
    for rec in records:  # the latest first: dicts keep that order, and max keeps the first of equals
        p = rec["params"]
        if p.get("job") == MEASURED_JOB:
            where = counts.setdefault(data_setting(p, rec.get("tags")), {})
            where[p.get("measured.setting")] = where.get(p.get("measured.setting"), 0) + 1
    out = {}
    for where, settings in counts.items():
        main = max(settings, key=settings.get)
        out[where] = {s: "" if s == main else f" [setting {s}]" for s in settings}
    return out


def _add_measured(table: Table, gain: Table, rec: Mapping, where: str, seen: set[tuple]) -> None:
    """A measured job's ``test/acc_<variant>_<split>`` as rows "K per class, <split>" of ``table``, and each synthetic
    variant's difference from radar only in the same job (same seed, same K rows) in ``gain``: the variants, test
    splits and K from the job's parameters ``measured.*`` (handradar.tasks.measured.run_measured)."""
    p, metrics = rec["params"], rec["metrics"]
    k = p.get("measured.per_class", "?")
    order = 10**9 if k == "all" else int(k) if k.isdigit() else -1
    for split in filter(None, p.get("measured.tests", "").split(",")):
        row = f"{k} per class, {split}{where}"
        cell = (table.name, row, p.get("seed"))
        if p.get("seed") is not None and cell in seen:
            continue
        seen.add(cell)
        base = metrics.get(f"test/acc_radar_only_{split}")
        for variant in filter(None, p.get("measured.variants", "").split(",")):
            value = metrics.get(f"test/acc_{variant}_{split}")
            if value is None:
                continue
            table.add(row, MEASURED_VARIANTS[variant], value, (where, split, order), rec.get("provenance"))
            if variant != "radar_only" and base is not None:
                gain.add(row, MEASURED_VARIANTS[variant], value - base, (where, split, order), rec.get("provenance"))


def job_table(params: Mapping[str, str], metrics: Mapping[str, float]) -> str:
    """The table rows of one finished job (what train.py prints at its end)."""
    tables = build_tables([{"params": params, "metrics": metrics}])
    return "\n\n".join(t.markdown() for t in tables) if tables else "(no table metrics)"


def load_records(tracking_uri: str) -> list[dict]:
    """Finished handradar runs as ``{"params", "metrics", "tags", "run_id", "provenance"}``, latest per job hash,
    the latest first."""
    if not store_exists(tracking_uri):  # nothing has run yet
        log.warning("no MLflow store at %s", tracking_uri)
        return []
    tracker = Tracker(tracking_uri, "", retries=8)

    def search(client) -> list:
        exps = [e.experiment_id for e in client.search_experiments()]
        runs, token = [], None
        while exps:  # pages of 1000 runs
            page = client.search_runs(exps, filter_string="attributes.status = 'FINISHED'", max_results=1000,
                                      order_by=["attributes.start_time DESC"], page_token=token)
            runs += list(page)
            token = page.token
            if not token:
                break
        return runs

    latest: dict[str, dict] = {}
    for run in tracker._call(search):
        tags = run.data.tags
        key = tags.get(f"{TAG_PREFIX}job_hash")
        if key is None or key in latest:  # not a handradar job, or an older run of the same job
            continue
        params = dict(run.data.params)
        latest[key] = {"params": params, "metrics": dict(run.data.metrics), "tags": dict(tags),
                       "run_id": run.info.run_id, "provenance": provenance(tags, params, job_overrides(tags))}
    return list(latest.values())


def job_overrides(tags: Mapping[str, str]) -> list[str] | None:
    """The command-line overrides Hydra kept in the run folder (``.hydra/overrides.yaml``), if it still exists."""
    path = Path(tags.get(f"{TAG_PREFIX}run_dir", "")) / ".hydra" / "overrides.yaml"
    if not tags.get(f"{TAG_PREFIX}run_dir") or not path.is_file():
        return None
    try:
        got = yaml.safe_load(path.read_text())
    except yaml.YAMLError:
        return None  # an unreadable folder only costs the row its exact command
    return [str(o) for o in got] if isinstance(got, list) else None
