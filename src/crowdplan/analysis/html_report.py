"""The evaluation report: one self-contained HTML page (docs/report.md) and its Markdown tables.

``crowdplan report --out DIR`` reads the committed result folders under ``results/`` only:

- ``results/records/<world>/<method>/`` (``crowdplan eval --record``): quantitative and social
  metrics, strategies, attention, paired comparisons, rendered examples;
- ``results/train/<run>/`` (and its ``test``, ``test-square``): intervals across seeds, training
  curves, training time, robustness from circle to square;
- ``results/generalization/<world>/<planner>/``: the transfer table;
- ``results/orca/<scenario>/``: the ORCA rows.

A method that lands later in any of these folders appears when the report is made again. Images
are embedded (base64), so ``DIR/index.html`` is one file; ``DIR/tables.md`` holds the tables.
"""

from __future__ import annotations

import base64
import html
import json
import math
import re
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from crowdplan.analysis import attention, curves, stats, strategies
from crowdplan.analysis.report import TRAINING_HEADER, interval_cell, training_rows
from crowdplan.evaluation import format_value
from crowdplan.evaluation_records import (
    RecordedRun,
    load_recorded,
    read_episodes,
    recorded_folders,
)
from crowdplan.io import atomic_write

REFERENCE = "lsa-dsac"  # the shipped model every comparison is made against
PAPER_PAGE = Path("docs/paper.md")
GIF_CASES = ((REFERENCE, 1), ("orca", 1))  # (recorded method, test case) animated in the report


@dataclass
class Table:
    """A table shown in HTML and written as Markdown."""

    title: str
    header: list[str]
    rows: list[list[str]]
    note: str = ""

    def markdown(self) -> str:
        lines = [f"### {self.title}", ""]
        if self.note:
            lines += [self.note, ""]
        lines += ["| " + " | ".join(self.header) + " |", "|" + "---|" * len(self.header)]
        lines += ["| " + " | ".join(row) + " |" for row in self.rows]
        return "\n".join(lines) + "\n"

    def html(self) -> str:
        head = "".join(f"<th>{html.escape(h)}</th>" for h in self.header)
        body = "".join(
            "<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in row) + "</tr>"
            for row in self.rows
        )
        note = f"<p class='note'>{html.escape(self.note)}</p>" if self.note else ""
        return (
            f"<h3>{html.escape(self.title)}</h3>{note}"
            f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"
        )


@dataclass
class Section:
    """A part of the page: text, the commands that made its data, tables and images."""

    title: str
    commands: list[str]
    text: str = ""
    tables: list[Table] = field(default_factory=list)
    images: list[tuple[str, bytes, str]] = field(default_factory=list)  # (caption, data, mime)
    gallery: bool = False  # images side by side


# ------------------------------------------------------------------ reading
def _summary(folder: Path) -> dict:
    return json.loads((folder / "summary.json").read_text())


def _value(summary: dict, key: str, digits: int = 3) -> str:
    return format_value((summary.get(key) or {}).get("value"), digits)


def eval_command(folder: Path, summary: dict, record: bool = False) -> str:
    """The ``crowdplan eval`` command that wrote a result folder, rebuilt from its meta."""
    meta = summary.get("meta", {})
    world = meta.get("world", {})
    model = meta.get("model")
    if model:
        path = Path(model)
        shipped = path.parent.parent.name == "models" and path.name == "model.pt"
        source = f"--model {path.parent.name if shipped else model}"
    else:
        source = f"--policy {meta.get('policy', '?')}"
    parts = ["crowdplan eval", source]
    if meta.get("default_world"):
        parts.append("--default-world")
    if world.get("scenario", "circle_crossing") != "circle_crossing":
        parts.append(f"--scenario {world['scenario']}")
    if world.get("humans", 5) != 5:
        parts.append(f"--humans {world['humans']}")
    parts.append(f"--episodes {summary.get('episodes', {}).get('value', 500)}")
    if record:
        parts.append("--record")
    parts.append(f"--out {folder}")
    return " ".join(parts)


def paper_table(title_fragment: str, page: Path = PAPER_PAGE) -> list[dict[str, str]]:
    """Rows of the first Markdown table under the heading of docs/paper.md that contains
    ``title_fragment`` (header cells as keys); empty when the page or table is missing."""
    if not page.is_file():
        return []
    text = page.read_text()
    heading = re.search(rf"^##[^\n]*{re.escape(title_fragment)}[^\n]*$", text, re.M)
    if not heading:
        return []
    lines = [
        line
        for line in text[heading.end() :].split("\n## ")[0].splitlines()
        if line.startswith("|")
    ]
    if len(lines) < 3:
        return []
    cells = [[c.strip() for c in line.strip("|").split("|")] for line in lines]
    return [dict(zip(cells[0], row, strict=False)) for row in cells[2:]]


def paper_method(run: RecordedRun | dict) -> str | None:
    """The paper's name of the method a result folder evaluates (None if the paper has none)."""
    meta = run.summary.get("meta", {}) if isinstance(run, RecordedRun) else run.get("meta", {})
    policy = str(meta.get("policy", ""))
    encoder = meta.get("encoder")
    algo = meta.get("algo", "dsac" if encoder else None)  # older DSAC results name no algo
    if policy == "orca":
        return "ORCA"
    if algo == "dsac" and encoder in ("lsa", "rg"):
        return f"{encoder.upper()}-DSAC"
    names = {"sarl": "SARL", "cadrl": "CADRL", "lstm_rl": "LSTM-RL", "lstm_a2c": "LSTM-A2C"}
    return next((v for k, v in names.items() if policy.startswith(k)), None)


def _label(folder: Path) -> str:
    return folder.name


# ------------------------------------------------------------------ images
def _png(fig) -> bytes:
    import io

    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=80)
    return buffer.getvalue()


def _render(write: Callable[[Path], object], suffix: str) -> bytes:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"image{suffix}"
        write(path)
        return path.read_bytes()


def _case_title(run: RecordedRun, k: int) -> str:
    ep = run.episodes[k]
    return f"{_label(run.folder)}, test case {ep.seed - 1000}: {ep.outcome} at {ep.time:.2f} s"


# ------------------------------------------------------------------ sections
def quantitative(runs: dict[str, RecordedRun]) -> Section:
    keys = [
        ("success_rate", "success"),
        ("collision_rate", "collision"),
        ("timeout_rate", "timeout"),
        ("time_to_goal", "time to goal (s)"),
        ("mean_distance", "mean dist (m)"),
        ("mean_reward", "mean reward"),
    ]
    social = [
        ("spl", "SPL"),
        ("path_irregularity", "path irreg. (rad)"),
        ("jerk", "jerk (m/s^3)"),
        ("angular_jerk", "ang. jerk (rad/s^3)"),
        ("personal_space_intrusion", "personal space"),
        ("min_ttc", "min TTC (s)"),
        ("mean_human_distance", "mean gap (m)"),
    ]
    main = Table(
        "The paper's six metrics (95% intervals)", ["method", "cases"] + [k[1] for k in keys], []
    )
    soc = Table(
        "Social-navigation metrics (docs/metrics.md)", ["method"] + [k[1] for k in social], []
    )
    for name, run in runs.items():
        s = run.summary
        cells = [interval_cell(s.get(k)) for k, _ in keys]
        main.rows.append([name, str(len(run.episodes)), *cells])
        soc.rows.append([name] + [interval_cell(s.get(k)) for k, _ in social])
    for row in paper_table("Test results"):
        method = row.get("method", "?")
        main.rows.append(
            [f"paper: {method}", "500"]
            + [row.get(h, "-") for h in ("success", "collision", "timeout", "time to goal (s)")]
            + [row.get("mean dist (m)", "-"), row.get("mean reward", "-")]
        )
    main.note = "Rows 'paper: ...' are the paper's table VI (docs/paper.md), on its own simulator."
    commands = ["make records"] + [eval_command(r.folder, r.summary, True) for r in runs.values()]
    return Section(
        "Quantitative results: 500 circle_crossing test cases", commands, tables=[main, soc]
    )


def significance(runs: dict[str, RecordedRun], train_tests: list[Path], world: str) -> Table:
    """Paired comparisons of the reference with every other evaluation of the same cases."""
    table = Table(
        f"Paired comparisons with {REFERENCE} on the same {world} test cases",
        stats.COMPARISON_HEADER,
        [],
        note=f"McNemar's exact test on the cases where exactly one planner succeeded (collided); "
        f"paired bootstrap ({stats.BOOTSTRAP_RESAMPLES} resamples, seed {stats.BOOTSTRAP_SEED}) "
        "of the time to goal over the cases both reached.",
    )
    if REFERENCE not in runs:
        return table
    ref = runs[REFERENCE]
    others = [(name, run.folder) for name, run in runs.items() if name != REFERENCE]
    others += [(f"{p.parent.name}/{p.name}", p) for p in train_tests]
    for name, folder in others:
        if same_cases(ref.summary, _summary(folder)):
            episodes = read_episodes(folder / "episodes.jsonl")
            table.rows.append(stats.compare(ref.episodes, episodes, REFERENCE, name).row())
    return table


def same_cases(a: dict, b: dict) -> bool:
    """Whether two evaluations ran the same cases: same seeds and the same world settings they
    both name (an option that older results do not name did not exist yet, which plays as its
    default; the frame actions are expressed in does not change a case)."""
    meta_a, meta_b = a.get("meta", {}), b.get("meta", {})
    world_a, world_b = meta_a.get("world", {}), meta_b.get("world", {})
    shared = (set(world_a) & set(world_b)) - {"action_frame"}
    return meta_a.get("seeds") == meta_b.get("seeds") and all(
        world_a[k] == world_b[k] for k in shared
    )


def strategy_section(runs: dict[str, RecordedRun]) -> Section:
    table = Table(
        "Strategies of every test episode (share of the 500 cases)",
        ["method", *strategies.STRATEGIES, "dominant", "paper's dominant (table V)"],
        [],
        note="Rules: docs/strategies.md. The paper names the dominant strategies of 50 sampled "
        "trajectories per method by inspection; here every episode is classified by the rules.",
    )
    labels: dict[str, list[str]] = {}
    for name, run in runs.items():
        labels[name] = strategies.classify_run(run.records)
        share = strategies.distribution(labels[name])
        paper = strategies.PAPER_DOMINANT.get(paper_method(run) or "", ())
        table.rows.append(
            [name]
            + [f"{100 * share[s]:.1f}%" for s in strategies.STRATEGIES]
            + [", ".join(strategies.dominant(labels[name])), ", ".join(paper) or "-"]
        )
    section = Section(
        "Strategies (the paper's tables IV and V, figure 8)",
        ["make records", "crowdplan report --out docs/report"],
        tables=[table],
    )
    section.gallery = True
    from crowdplan.sim.render import save_png

    order = [REFERENCE] + [n for n in runs if n != REFERENCE]
    for strategy in strategies.STRATEGIES:
        found = next(
            (
                (n, labels[n].index(strategy))
                for n in order
                if n in labels and strategy in labels[n]
            ),
            None,
        )
        if found is None:
            section.text += f" No recorded episode is a {strategy}."
            continue
        name, k = found
        run = runs[name]
        title = f"{strategy}: {_case_title(run, k)}"
        data = _render(lambda p, r=run, i=k, t=title: save_png(r.records.trace(i), p, t), ".png")
        section.images.append((title, data, "image/png"))
    return section


def attention_section(runs: dict[str, RecordedRun]) -> Section:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from crowdplan.sim.render import draw_trace

    table = Table(
        "Attention against what the model saw (every decision of the 500 episodes)",
        [
            "model",
            "samples",
            "Spearman: gap",
            "Spearman: closing speed",
            "Spearman: time to collision",
            "top = nearest",
            "top = soonest to collide",
            "chance",
        ],
        [],
        note="Samples are (decision, human) pairs; gap is edge to edge; an infinite time to "
        "collision ranks above every finite one. 'top = ...': share of decisions (>= 2 humans) "
        "where the most attended human is the nearest / the soonest to collide.",
    )
    with_scores = {n: r for n, r in runs.items() if r.records.has_scores}
    fig = Figure(figsize=(10, 3.4), layout="constrained")
    FigureCanvasAgg(fig)
    ax_gap, ax_ttc = fig.subplots(1, 2)
    for name, run in with_scores.items():
        s = attention.samples(run.records)
        c = attention.correlations(s)
        table.rows.append(
            [name, f"{int(c['samples'])}"]
            + [f"{c[k]:+.3f}" for k in ("spearman_gap", "spearman_closing_speed", "spearman_ttc")]
            + [f"{c[k]:.3f}" for k in ("top_is_nearest", "top_is_soonest", "chance")]
        )
        x, m = attention.binned_means(s.gap, s.score, np.linspace(0, 6, 25))
        ax_gap.plot(x, m, label=name)
        finite = np.isfinite(s.ttc)
        x, m = attention.binned_means(s.ttc[finite], s.score[finite], np.linspace(0, 10, 21))
        ax_ttc.plot(x, m, label=name)
    ax_gap.set(xlabel="gap to the human (m)", ylabel="mean attention score")
    ax_ttc.set(xlabel="time to collision (s), finite ones", ylabel="mean attention score")
    for ax in (ax_gap, ax_ttc):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    section = Section(
        "Interpretability: attention (the paper's table III, figure 7)",
        ["make records", "crowdplan report --out docs/report"],
        tables=[table],
    )
    if with_scores:
        section.images.append(
            ("Mean attention by gap and by time to collision", _png(fig), "image/png")
        )
    if REFERENCE in with_scores:
        run = with_scores[REFERENCE]
        k = int(run.records.index_of(1001))
        trace = run.records.trace(k)
        snap = Figure(figsize=(12, 4.4), layout="constrained")
        FigureCanvasAgg(snap)
        moments = np.linspace(0, len(trace.robot_vel) - 1, 3).astype(int)
        for ax, t in zip(snap.subplots(1, 3), moments, strict=True):
            draw_trace(ax, trace, upto=int(t))
            ax.set_title(f"t = {t * trace.dt:.2f} s", fontsize=9)
        caption = (
            f"Attention of each human (number, shading) at three moments: {_case_title(run, k)}"
        )
        section.images.append((caption, _png(snap), "image/png"))
    return section


def seeds_section(train: Path) -> Section:
    """Per method: mean over seeds with a Student-t interval, and the per-seed rows."""
    groups: dict[str, list[Path]] = {}
    for run in curves.discover_runs(train):
        if (run.folder / "test" / "summary.json").is_file():
            groups.setdefault(run.method, []).append(run.folder)
    keys = [
        ("success_rate", "success"),
        ("collision_rate", "collision"),
        ("time_to_goal", "time to goal (s)"),
        ("mean_reward", "mean reward"),
    ]
    summary_table = Table(
        "Across seeds: mean [95% Student-t interval, clipped to 0..1 for rates] of the "
        "per-seed test results",
        ["method", "seeds"] + [k[1] for k in keys],
        [],
    )
    seed_rows = Table(
        "Per seed (500 circle_crossing test cases)", ["run", "seed"] + [k[1] for k in keys], []
    )
    for method, folders in sorted(groups.items()):
        results = [_summary(f / "test") for f in folders]
        cells = []
        for key, _ in keys:
            bounds = (0.0, 1.0) if key.endswith("_rate") else (-math.inf, math.inf)
            s = stats.across_seeds([(r.get(key) or {}).get("value") for r in results], bounds)
            cells.append("n/a" if math.isnan(s.mean) else s.text())
        summary_table.rows.append([method, str(len(folders))] + cells)
        for f, r in zip(folders, results, strict=True):
            seed = str(r.get("meta", {}).get("seed", "?"))
            seed_rows.rows.append([f.name, seed] + [_value(r, k) for k, _ in keys])
    return Section(
        "Results across training seeds",
        ["make publish RUN=runs/<run>   # per run: copies the run, tests best_model.pt"],
        tables=[summary_table, seed_rows],
    )


def curves_section(train: Path) -> Section:
    runs = curves.discover_runs(train)
    section = Section(
        "Training curves (the paper's figure 6)",
        ["crowdplan train --config configs/<preset>.yaml --seed S", "make publish RUN=runs/<run>"],
    )
    if not runs:
        section.text = f"No training runs under {train}."
        return section
    png, drawn = curves.draw_panels(runs)
    section.images.append(
        (
            f"Discounted return per training episode, rolling mean of {curves.SMOOTHING}; "
            "band: lowest to highest seed",
            png,
            "image/png",
        )
    )
    missing = [p.title for p in curves.PANELS if p.key not in {d.key for d, _ in drawn}]
    if missing:
        section.text = "Panels without the runs they need (yet): " + "; ".join(missing) + "."
    section.tables.append(
        Table(
            "Training time",
            TRAINING_HEADER,
            training_rows([r.folder for r in runs]),
            note="Hours per 10k episodes on the machines of docs/results.md, not the paper's.",
        )
    )
    return section


def transfer_tables(generalization: Path) -> list[Table]:
    """Success (collision) and time to goal of every planner in every test world, then per world
    the paired comparisons with the reference planner."""
    worlds = (
        sorted(p.name for p in generalization.iterdir() if p.is_dir())
        if generalization.is_dir()
        else []
    )
    planners = sorted({p.parent.name for p in generalization.glob("*/*/summary.json")})
    table = Table(
        "Success (collision) rate of every planner in every test world, 500 cases each",
        ["planner", *worlds],
        [],
        note="Worlds: crowdplan.analysis.test_worlds (docs/scenarios.md).",
    )
    times = Table(
        "Time to goal (s) of every planner in every test world, mean over the cases it reached",
        ["planner", *worlds],
        [],
    )
    tests: list[Table] = []
    for planner in planners:
        row, time_row = [planner], [planner]
        for world in worlds:
            path = generalization / world / planner / "summary.json"
            if path.is_file():
                s = json.loads(path.read_text())
                row.append(f"{_value(s, 'success_rate')} ({_value(s, 'collision_rate')})")
                time_row.append(_value(s, "time_to_goal", 2))
            else:
                row.append("-")
                time_row.append("-")
        table.rows.append(row)
        times.rows.append(time_row)
    for world in worlds:
        folder = generalization / world
        if not (folder / REFERENCE / "episodes.jsonl").is_file():
            continue
        ref = read_episodes(folder / REFERENCE / "episodes.jsonl")
        t = Table(f"{world}: paired comparisons with {REFERENCE}", stats.COMPARISON_HEADER, [])
        ref_summary = _summary(folder / REFERENCE)
        for planner in planners:
            path = folder / planner / "episodes.jsonl"
            if planner == REFERENCE or not path.is_file():
                continue
            if same_cases(ref_summary, _summary(folder / planner)):
                t.rows.append(stats.compare(ref, read_episodes(path), REFERENCE, planner).row())
        tests.append(t)
    return [table, times, *tests]


def robustness_table(train: Path) -> Table:
    """Absolute change of each metric from circle_crossing to square_crossing, per run."""
    robust = Table(
        "Robustness: circle_crossing -> square_crossing (models trained on circle)",
        [
            "run",
            "success circle",
            "success square",
            "|change|",
            "collision |change|",
            "time to goal |change| (s)",
            "paper's square success",
        ],
        [],
    )
    paper_square = (paper_table("Transfer to square_crossing") or [{}])[0]
    for run in curves.discover_runs(train):
        a, b = run.folder / "test" / "summary.json", run.folder / "test-square" / "summary.json"
        if not (a.is_file() and b.is_file()):
            continue
        sa, sb = json.loads(a.read_text()), json.loads(b.read_text())

        def delta(key: str, x=sa, y=sb) -> str:
            u, v = (x.get(key) or {}).get("value"), (y.get(key) or {}).get("value")
            return "n/a" if u is None or v is None else f"{abs(u - v):.3f}"

        robust.rows.append(
            [
                run.folder.name,
                _value(sa, "success_rate"),
                _value(sb, "success_rate"),
                delta("success_rate"),
                delta("collision_rate"),
                delta("time_to_goal"),
                paper_square.get(paper_method(sa) or "", "-"),
            ]
        )
    return robust


def transfer_section(generalization: Path, train: Path) -> Section:
    commands = [
        "python -m crowdplan.analysis.test_worlds --out results/generalization lsa-dsac "
        "lsa-dsac-paper lsa-dsac-paper-goal orca straight  # make generalization",
    ]
    table, times, *tests = transfer_tables(generalization)
    tables = [table, times, robustness_table(train), *tests]
    return Section("Transfer and robustness", commands, tables=tables)


def gifs(runs: dict[str, RecordedRun]) -> Section:
    from crowdplan.sim.render import save_gif

    section = Section(
        "Animations", ["crowdplan render --model lsa-dsac --case 1 --out case1.gif"], gallery=True
    )
    for name, case in GIF_CASES:
        if name not in runs:
            continue
        run = runs[name]
        k = run.records.index_of(1000 + case)
        title = _case_title(run, k)
        data = _render(lambda p, r=run, i=k, t=title: save_gif(r.records.trace(i), p, t), ".gif")
        section.images.append((title, data, "image/gif"))
    return section


# ------------------------------------------------------------------ page
STYLE = """
body{font-family:sans-serif;max-width:1200px;margin:1em auto;padding:0 1em;color:#222}
table{border-collapse:collapse;margin:.5em 0 1.5em;font-size:13px}
th,td{border:1px solid #bbb;padding:3px 6px;text-align:left}th{background:#eee}
pre{background:#f4f4f4;padding:6px;overflow-x:auto;font-size:12px}
figure{margin:1em 0}img{max-width:100%;border:1px solid #ddd}
figcaption{font-size:13px;color:#555}.note{font-size:13px;color:#555}
figure.gallery{display:inline-block;width:32%;vertical-align:top;margin:0 .5% 1em 0}
"""


def render_page(sections: list[Section], title: str) -> str:
    parts = [
        f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
        f"<style>{STYLE}</style></head><body><h1>{html.escape(title)}</h1>",
        "<ul>"
        + "".join(
            f"<li><a href='#s{i}'>{html.escape(s.title)}</a></li>" for i, s in enumerate(sections)
        )
        + "</ul>",
    ]
    for i, s in enumerate(sections):
        parts.append(f"<h2 id='s{i}'>{html.escape(s.title)}</h2>")
        if s.commands:
            parts.append("<pre>" + html.escape("\n".join(s.commands)) + "</pre>")
        if s.text:
            parts.append(f"<p>{html.escape(s.text.strip())}</p>")
        parts += [t.html() for t in s.tables]
        for caption, data, mime in s.images:
            b64 = base64.b64encode(data).decode()
            css = " class='gallery'" if s.gallery else ""
            parts.append(
                f"<figure{css}><img alt='{html.escape(caption)}' src='data:{mime};base64,{b64}'>"
                f"<figcaption>{html.escape(caption)}</figcaption></figure>"
            )
    # The browser test reads how many images decoded from the rendered page.
    parts.append(
        "<script>addEventListener('load',()=>{document.body.dataset.imagesLoaded="
        "[...document.images].filter(i=>i.complete&&i.naturalWidth>0).length})</script>"
    )
    parts.append("</body></html>")
    return "\n".join(parts)


def build_report(out: str | Path, results: str | Path = "results") -> Path:
    """Write ``out/index.html`` and ``out/tables.md`` from the result folders under ``results``."""
    results, out = Path(results), Path(out)
    if not results.is_dir():
        raise FileNotFoundError(f"result folder {results} does not exist")
    recorded = recorded_folders(results / "records")
    circle = {_label(f): load_recorded(f) for f in recorded if f.parent.name == "circle"}
    square = {_label(f): load_recorded(f) for f in recorded if f.parent.name == "square"}
    train = results / "train"
    sections = [
        Section(
            "How this page was made",
            ["make records   # once: the recorded evaluations", "make report   # this page"],
            text="Every number below is computed from the committed result folders named in "
            "each section; docs/report.md explains how to read the page.",
        )
    ]
    if circle:
        quant = quantitative(circle)
        tests = [p.parent for p in sorted(train.glob("*/test/summary.json"))]
        orca = (
            [results / "orca" / "circle_crossing"]
            if (results / "orca" / "circle_crossing" / "episodes.jsonl").is_file()
            else []
        )
        quant.tables.append(significance(circle, tests + orca, "circle_crossing"))
        if square:
            squares = [p.parent for p in sorted(train.glob("*/test-square/summary.json"))]
            quant.tables.append(significance(square, squares, "square_crossing"))
        sections += [quant, strategy_section(circle), attention_section(circle)]
    if train.is_dir():
        sections += [seeds_section(train), curves_section(train)]
    sections.append(transfer_section(results / "generalization", train))
    if circle:
        sections.append(gifs(circle))
    page = render_page(sections, "crowdplan evaluation report")
    atomic_write(out / "index.html", lambda f: f.write(page))
    markdown = (
        "# crowdplan evaluation report: tables\n\nMade by `crowdplan report --out "
        f"{out}` from `{results}`.\n\n"
    )
    markdown += "\n".join(t.markdown() for s in sections for t in s.tables)
    atomic_write(out / "tables.md", lambda f: f.write(markdown))
    return out / "index.html"
