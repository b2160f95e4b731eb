"""The paper's comparison tables II, VI, VII, VIII and IX: our runs beside the paper's values.

``crowdplan report --paper METHOD=DIR [METHOD=DIR ...]`` prints them, and a block
``<!-- crowdplan report --paper METHOD=DIR ... -->`` of a markdown page is filled with them by
``crowdplan report --fill``. METHOD is one of :data:`METHODS`; DIR is a training run folder
published under ``results/train/`` (``test/`` and ``test-square/`` inside) or, for ORCA, a planner
folder holding ``circle_crossing/`` and ``square_crossing/``. Naming a method several times gives
one row over its runs (seeds). ``METHOD?=DIR`` names a run that may not exist yet: until it does,
its row says "not trained". A method not named at all gets the same row. Every row shows the
paper's value (docs/paper.md) beside ours.

The converged reward (table II) is the mean validation reward (100 validation cases) over the
last :data:`CONVERGED_LAST` validations of a run; the paper's is "the validation mean reward at
the end of training". Robustness (table IX) is the absolute change of the success rate from
circle_crossing to square_crossing; the paper's is derived from its tables VI and VIII.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import yaml

from crowdplan.analysis.html_report import PAPER_PAGE, Table, paper_method, paper_table
from crowdplan.analysis.report import interval_cell as cell
from crowdplan.analysis.report import read_run
from crowdplan.analysis.stats import across_seeds
from crowdplan.evaluation import format_value

METHODS = ("ORCA", "CADRL", "LSTM-RL", "SARL", "LSTM-A2C", "RG-DSAC", "LSA-DSAC")
PLANNERS = ("ORCA",)  # evaluated as they are, never trained
CONVERGED_LAST = 3
TEST_CASES, TEST_HUMANS = 500, 5  # the setting of every row of the paper's tables
CIRCLE_FOLDERS = ("test", "circle_crossing")  # a training run's, a planner's
SQUARE_FOLDERS = ("test-square", "square_crossing")
PAPER_SECTIONS = {
    "II": "Converged validation reward",
    "VI": "Test results",
    "VII": "Training time",
    "VIII": "Transfer to square_crossing",
}
VI_METRICS = (  # (summary key, the paper's column, digits)
    ("success_rate", "success", 3),
    ("time_to_goal", "time to goal (s)", 2),
    ("collision_rate", "collision", 3),
    ("timeout_rate", "timeout", 3),
    ("mean_distance", "mean dist (m)", 3),
    ("mean_reward", "mean reward", 3),
)
USAGE = "METHOD=DIR, or METHOD?=DIR for a run that may not be trained yet"


@dataclass(frozen=True)
class Run:
    """One result folder of a method: its 500 circle and square test summaries and, for a
    trained model, its run metadata, validation log and configuration."""

    folder: Path
    circle: dict
    square: dict | None
    meta: dict | None = None
    validations: tuple[dict[str, str], ...] = ()
    config: dict | None = None

    @property
    def converged_reward(self) -> float | None:
        """Mean validation reward over the last :data:`CONVERGED_LAST` validations."""
        last = [float(v["mean_reward"]) for v in self.validations[-CONVERGED_LAST:]]
        return sum(last) / len(last) if last else None

    @property
    def validated_elsewhere(self) -> bool:
        """Whether the run validated with another crowd size than it trained with (CADRL
        trained with one human and validated with five): its converged reward is then not the
        paper's, which is measured in the training world."""
        if self.config is None:
            return False
        val_humans = self.config.get("val_humans")
        return val_humans is not None and val_humans != self.config["world"]["humans"]

    def value(self, key: str, scenario: str = "circle") -> float | None:
        """A metric of the circle (or ``scenario="square"``) test; None when not measured."""
        summary = self.circle if scenario == "circle" else self.square
        return ((summary or {}).get(key) or {}).get("value")

    def robustness(self) -> float | None:
        """Absolute change of the success rate from circle_crossing to square_crossing."""
        a, b = self.value("success_rate"), self.value("success_rate", "square")
        return None if a is None or b is None else abs(a - b)


def parse_args(args: list[str]) -> dict[str, list[tuple[Path, bool]]]:
    """``METHOD=DIR`` / ``METHOD?=DIR`` words -> {method: [(folder, may be missing), ...]}."""
    if not args:
        raise ValueError(f"--paper needs {USAGE}; methods: {', '.join(METHODS)}")
    named: dict[str, list[tuple[Path, bool]]] = {}
    for word in args:
        method, sep, folder = word.partition("=")
        optional = method.endswith("?")
        method = method.removesuffix("?")
        if not sep or not method or not folder:
            raise ValueError(f"--paper takes {USAGE}, got '{word}'; methods: {', '.join(METHODS)}")
        if method not in METHODS:
            raise ValueError(
                f"unknown method '{method}' in '{word}'; the paper's methods: {', '.join(METHODS)}"
            )
        if any(Path(folder) == f for f, _ in named.get(method, [])):
            raise ValueError(f"'{word}': {folder} is named twice for {method}")
        named.setdefault(method, []).append((Path(folder), optional))
    return named


def _summary(folder: Path, names: tuple[str, ...]) -> tuple[Path, dict] | None:
    for name in names:
        path = folder / name / "summary.json"
        if path.is_file():
            return path, json.loads(path.read_text())
    return None


def load_run(method: str, folder: Path) -> Run:
    """The results of ``folder``, checked to be ``method``'s 500-case tests with 5 humans."""
    found = _summary(folder, CIRCLE_FOLDERS)
    if found is None:
        raise FileNotFoundError(
            f"{method}={folder}: no {' or '.join(f'{n}/summary.json' for n in CIRCLE_FOLDERS)} "
            "(the 500 circle_crossing test cases)"
        )
    path, circle = found
    evaluated = paper_method(circle)
    if evaluated != method:
        raise ValueError(
            f"{method}={folder}: {path} evaluates {evaluated or 'no method of the paper'}, "
            f"not {method}"
        )
    square_found = _summary(folder, SQUARE_FOLDERS)
    tests = [("circle_crossing", found)] + [("square_crossing", square_found)] * bool(square_found)
    for scenario, (path, summary) in tests:
        world = summary.get("meta", {}).get("world", {})
        setting = (world.get("scenario"), world.get("humans"), summary["episodes"]["value"])
        if setting != (scenario, TEST_HUMANS, TEST_CASES):
            raise ValueError(
                f"{method}={folder}: {path} tests {setting[2]} {setting[0]} cases with "
                f"{setting[1]} humans; the paper's tables are {TEST_CASES} {scenario} cases "
                f"with {TEST_HUMANS} humans"
            )
    square = square_found[1] if square_found else None
    if method in PLANNERS:
        return Run(folder, circle, square)
    needed = ("meta.json", "validation.csv", "config.yaml")
    if not all((folder / name).is_file() for name in needed):
        raise FileNotFoundError(
            f"{method}={folder}: not a training run folder (it needs {', '.join(needed)})"
        )
    meta, validations = read_run(folder)
    config = yaml.safe_load((folder / "config.yaml").read_text())
    return Run(folder, circle, square, meta, tuple(validations), config)


def load_methods(args: list[str]) -> dict[str, list[Run]]:
    """Every method of the paper -> its runs (empty: not trained, or not named)."""
    runs: dict[str, list[Run]] = {m: [] for m in METHODS}
    for method, folders in parse_args(args).items():
        for folder, optional in folders:
            if folder.exists():
                runs[method].append(load_run(method, folder))
            elif not optional:
                raise FileNotFoundError(
                    f"{method}={folder}: folder does not exist "
                    f"(write {method}?={folder} for a run that is not trained yet)"
                )
    return runs


def paper_values(page: Path = PAPER_PAGE) -> dict[str, dict[str, dict[str, str] | str]]:
    """The paper's tables from docs/paper.md: {"VI": {method: row}, "II": {method: value}, ...}."""
    values: dict[str, dict] = {}
    for table, heading in PAPER_SECTIONS.items():
        rows = paper_table(heading, page)
        if not rows:
            raise FileNotFoundError(f"{page}: no Markdown table under a '{heading}' heading")
        values[table] = {r["method"]: r for r in rows} if table == "VI" else rows[0]
    return values


# ------------------------------------------------------------------ cells
def _missing(method: str) -> str:
    return "not evaluated" if method in PLANNERS else "not trained"


def _names(runs: list[Run]) -> str:
    return ", ".join(r.folder.name for r in runs)


def _across(values: list[float | None], digits: int, rate: bool = False) -> str:
    """One value, or the mean over seeds with its Student-t interval and the seed count."""
    known = [v for v in values if v is not None]
    if not known:
        return "n/a"
    if len(values) == 1:
        return format_value(known[0], digits)
    return across_seeds(known, (0.0, 1.0) if rate else (-math.inf, math.inf)).text(digits)


def _metric(runs: list[Run], key: str, digits: int, scenario: str = "circle") -> str:
    """A test metric: with one run its value and 500-case 95% interval, with several the mean
    over runs and its interval over runs."""
    if len(runs) == 1:
        summary = runs[0].circle if scenario == "circle" else runs[0].square
        return cell((summary or {}).get(key) or {}, digits)
    return _across([r.value(key, scenario) for r in runs], digits, key.endswith("_rate"))


def _training(run: Run) -> str:
    """How a run was trained, as far as the paper's settings differ between methods."""
    if run.config is None:
        return "planner"
    humans = run.config["world"]["humans"]
    text = f"{humans} human{'s' if humans != 1 else ''}"
    lookahead = run.circle.get("meta", {}).get("lookahead") or (
        run.config.get("value_rl") or {}
    ).get("lookahead")
    if run.config.get("algo") == "value_rl" and lookahead:
        text += f", {lookahead} lookahead"
    dsac = run.config.get("dsac") if run.config.get("algo", "dsac") == "dsac" else None
    if dsac:  # the paper leaves it out; docs/training.md compares the readings
        text += f", target entropy {_target_entropy(dsac)}"
        if run.config.get("name"):  # the preset holds the rest of the recipe
            text += f" (preset {run.config['name']})"
    if run.validated_elsewhere:  # table II's reward is from that world
        text += f", validated with {run.config['val_humans']}"
    return text


def _target_entropy(dsac: dict) -> str:
    """A DSAC run's target entropy as its config gives it: absolute, or a share of log(actions)."""
    if dsac.get("target_entropy") is not None:
        return f"{dsac['target_entropy']:g}"
    return f"{dsac.get('target_entropy_scale', 0.98):g} log {dsac.get('n_actions', 81)}"


def _paper_float(text: str | None) -> float | None:
    try:
        return float(text)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return None


# ------------------------------------------------------------------ tables
def table_vi(runs: dict[str, list[Run]], paper: dict) -> Table:
    header = ["method", "run", "trained with"]
    for _, label, _ in VI_METRICS:
        header += [label, f"{label}, paper"]
    table = Table(
        f"Table VI: the {TEST_CASES} circle_crossing test cases, {TEST_HUMANS} humans",
        header,
        [],
        note="One run: its value [95% interval over the test cases]; several runs: their mean "
        "[95% Student-t interval over runs] (seeds). The paper's values are on its simulator.",
    )
    for method, group in runs.items():
        row = paper["VI"].get(method, {})
        if not group:
            cells = [_missing(method), "-"]
            for _, label, _ in VI_METRICS:
                cells += ["n/a", row.get(label, "-")]
        else:
            cells = [_names(group), "; ".join(sorted({_training(r) for r in group}))]
            for key, label, digits in VI_METRICS:
                cells += [_metric(group, key, digits), row.get(label, "-")]
        table.rows.append([method, *cells])
    return table


def table_ii(runs: dict[str, list[Run]], paper: dict) -> Table:
    table = Table(
        "Table II: converged validation reward",
        ["method", "run", "trained with", "validations used (episodes)", "ours", "paper"],
        [],
        note=f"Ours: the mean validation reward (100 validation cases) over the last "
        f"{CONVERGED_LAST} validations of each run; the paper's: the validation mean reward at "
        "the end of training.",
    )
    for method, group in runs.items():
        theirs = paper["II"].get(method, "-")
        if method in PLANNERS:
            table.rows.append([method, "planner: no training", "-", "-", "-", theirs])
        elif not group:
            table.rows.append([method, _missing(method), "-", "-", "n/a", theirs])
        else:
            used = "; ".join(
                ", ".join(v["episode"] for v in r.validations[-CONVERGED_LAST:]) for r in group
            )
            training = "; ".join(sorted({_training(r) for r in group}))
            ours = _across([r.converged_reward for r in group], 3)
            table.rows.append([method, _names(group), training, used, ours, theirs])
    return table


def table_vii(runs: dict[str, list[Run]], paper: dict) -> Table:
    table = Table(
        "Table VII: training hours per 10k episodes",
        [
            "method",
            "run",
            "device, torch threads",
            "episodes",
            "ours: RL h / 10k episodes",
            "ours: imitation learning (h)",
            "paper (its hardware)",
        ],
        [],
        note="Ours: wall-clock time of the RL episodes of each run, scaled to 10k episodes, on "
        "the machine and under the load it trained with (docs/results.md says which: not every "
        "run trained on the same machine); the imitation learning that precedes the RL of the "
        "value-network baselines is counted apart. The paper's hours are on its own hardware: "
        "compare methods within a column, not our column with the paper's.",
    )
    for method, group in runs.items():
        theirs = paper["VII"].get(method, "-")
        if method in PLANNERS:
            table.rows.append([method, "planner: no training", "-", "-", "-", "-", theirs])
        elif not group:
            table.rows.append([method, _missing(method), "-", "-", "n/a", "n/a", theirs])
        else:
            device = "; ".join(
                sorted(
                    {f"{r.config.get('device', 'cpu')}, {r.meta['torch_threads']}" for r in group}
                )
            )
            imitation = [
                (r.meta.get("pretrain_seconds") or 0.0) / 3600
                for r in group
                if r.config.get("algo") == "value_rl"
            ]
            table.rows.append(
                [
                    method,
                    _names(group),
                    device,
                    ", ".join(str(r.meta["episodes"]) for r in group),
                    _across([r.meta["hours_per_10k_episodes"] for r in group], 2),
                    _across(imitation, 2) if imitation else "-",
                    theirs,
                ]
            )
    return table


def table_viii(runs: dict[str, list[Run]], paper: dict) -> Table:
    table = Table(
        f"Table VIII: transfer to {TEST_CASES} square_crossing cases (trained on circle_crossing)",
        ["method", "run", "success", "success, paper"],
        [],
    )
    for method, group in runs.items():
        ours = _metric(group, "success_rate", 3, "square") if group else "n/a"
        name = _names(group) if group else _missing(method)
        table.rows.append([method, name, ours, paper["VIII"].get(method, "-")])
    return table


def paper_robustness(paper: dict, method: str) -> float | None:
    """The paper's absolute change of success, circle (table VI) -> square (table VIII)."""
    a = _paper_float(paper["VI"].get(method, {}).get("success"))
    b = _paper_float(paper["VIII"].get(method))
    return None if a is None or b is None else abs(a - b)


def table_ix(runs: dict[str, list[Run]], paper: dict) -> Table:
    table = Table(
        "Table IX: robustness, absolute change of success from circle_crossing to square_crossing",
        ["method", "run", "success circle", "success square", "abs. change", "abs. change, paper"],
        [],
        note="The paper's change is computed from its tables VI and VIII; several runs: the "
        "mean of the per-run changes.",
    )
    for method, group in runs.items():
        theirs = format_value(paper_robustness(paper, method))
        if not group:
            table.rows.append([method, _missing(method), "n/a", "n/a", "n/a", theirs])
            continue
        table.rows.append(
            [
                method,
                _names(group),
                _across([r.value("success_rate") for r in group], 3, rate=True),
                _across([r.value("success_rate", "square") for r in group], 3, rate=True),
                _across([r.robustness() for r in group], 3, rate=True),
                theirs,
            ]
        )
    return table


# ------------------------------------------------------------------ reading notes
Estimate = tuple[float | None, tuple[float, float] | None]  # value and its 95% interval
NOTE_GROUPS = (
    "as good as the paper or better",
    "worse, the paper's value inside our 95% interval",
    "worse than the paper",
    "no result yet",
    "not compared, validated with another crowd than trained with",
)


def _estimate(group: list[Run], key: str, scenario: str = "circle") -> Estimate:
    """A test metric of a method: one run's value and interval over the test cases, or the mean
    over runs and its interval over runs."""
    values = [r.value(key, scenario) for r in group]
    if len(group) == 1 and values[0] is not None:
        summary = group[0].circle if scenario == "circle" else group[0].square
        ci = ((summary or {}).get(key) or {}).get("ci95")
        return values[0], tuple(ci) if ci and ci[0] is not None else None
    return _over_runs(values, rate=key.endswith("_rate"))


def _over_runs(values: list[float | None], rate: bool = False) -> Estimate:
    """A per-run quantity of a method: one run's value, or the mean over runs with the interval
    the tables print beside it (rates bounded to [0, 1])."""
    known = [v for v in values if v is not None]
    if not known:
        return None, None
    if len(values) == 1:
        return known[0], None
    s = across_seeds(known, (0.0, 1.0) if rate else (-math.inf, math.inf))
    return s.mean, s.ci95


def _compare_line(
    what: str,
    ours: dict[str, Estimate],
    theirs: dict[str, float | None],
    higher: bool,
    not_compared: frozenset[str] = frozenset(),
) -> str:
    """'what: as good as the paper or better (A); worse ... (B); no result yet (C)', for the
    methods the paper gives a value for; ``not_compared`` methods are listed apart."""
    groups: dict[str, list[str]] = {g: [] for g in NOTE_GROUPS}
    for method in METHODS:
        b = theirs.get(method)
        if b is None:
            continue
        a, ci = ours.get(method, (None, None))
        if method in not_compared:
            group = NOTE_GROUPS[4]
        elif a is None:
            group = NOTE_GROUPS[3]
        elif (a >= b) if higher else (a <= b):
            group = NOTE_GROUPS[0]
        elif ci is not None and ci[0] <= b <= ci[1]:
            group = NOTE_GROUPS[1]
        else:
            group = NOTE_GROUPS[2]
        groups[group].append(method)
    return f"- {what}: " + "; ".join(f"{g} ({', '.join(m)})" for g, m in groups.items() if m) + "."


def reading_notes(runs: dict[str, list[Run]], paper: dict) -> str:
    """Which methods match or beat the paper's values, table by table (nothing else)."""
    vi, viii = paper["VI"], paper["VIII"]
    lines = [
        "Reading notes (generated from the tables above; a method is compared where the paper "
        "gives a value):",
        "",
        _compare_line(
            "Table VI, success",
            {m: _estimate(g, "success_rate") for m, g in runs.items()},
            {m: _paper_float(vi.get(m, {}).get("success")) for m in METHODS},
            higher=True,
        ),
        _compare_line(
            "Table VI, collision (lower is better)",
            {m: _estimate(g, "collision_rate") for m, g in runs.items()},
            {m: _paper_float(vi.get(m, {}).get("collision")) for m in METHODS},
            higher=False,
        ),
        _compare_line(
            "Table II, converged reward",
            {m: _over_runs([r.converged_reward for r in g]) for m, g in runs.items()},
            {m: _paper_float(paper["II"].get(m)) for m in METHODS},
            higher=True,
            not_compared=frozenset(
                m for m, g in runs.items() if any(r.validated_elsewhere for r in g)
            ),
        ),
        _compare_line(
            "Table VIII, square success",
            {m: _estimate(g, "success_rate", "square") for m, g in runs.items()},
            {m: _paper_float(viii.get(m)) for m in METHODS},
            higher=True,
        ),
        _compare_line(
            "Table IX, change of success (smaller is more robust)",
            {m: _over_runs([r.robustness() for r in g]) for m, g in runs.items()},
            {m: paper_robustness(paper, m) for m in METHODS},
            higher=False,
        ),
        "- Table VII: our hours and the paper's were measured on different hardware; they are "
        "not compared.",
    ]
    return "\n".join(lines) + "\n"


def paper_report(args: list[str], page: Path = PAPER_PAGE) -> str:
    """The five tables and their reading notes for the runs named by ``METHOD=DIR`` words."""
    runs = load_methods(args)
    paper = paper_values(page)
    tables = [fn(runs, paper) for fn in (table_ii, table_vi, table_vii, table_viii, table_ix)]
    return "\n".join(t.markdown() for t in tables) + "\n" + reading_notes(runs, paper)
