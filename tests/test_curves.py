"""Which variant a published training run is a seed of (report grouping, curve panels)."""

from __future__ import annotations

import yaml

from crowdplan.analysis.curves import PANELS, discover_runs, panel_lines


def _run(root, folder: str, name: str, seed: int, humans: int = 5, encoder: str = "lsa") -> None:
    run = root / folder
    run.mkdir()
    config = {"name": name, "seed": seed, "world": {"humans": humans}, "encoder": {"name": encoder}}
    (run / "config.yaml").write_text(yaml.safe_dump(config))
    (run / "episodes.csv").write_text("episode,discounted_return\n1,0.5\n")


def test_a_sweep_variant_is_its_own_method_though_its_config_keeps_the_preset_name(tmp_path):
    _run(tmp_path, "lsa_dsac_aln-s4", "lsa_dsac_aln", 4)
    _run(tmp_path, "lsa_dsac_aln_avgq-s4", "lsa_dsac_aln", 4)
    _run(tmp_path, "lsa_dsac_ent05-h1-s0", "lsa_dsac_ent05", 0, humans=1)
    _run(tmp_path, "my_run", "cadrl", 2, humans=1)  # not named <variant>-s<seed>
    methods = {run.folder.name: run.method for run in discover_runs(tmp_path)}
    assert methods == {
        "lsa_dsac_aln-s4": "lsa_dsac_aln",
        "lsa_dsac_aln_avgq-s4": "lsa_dsac_aln_avgq",
        "lsa_dsac_ent05-h1-s0": "lsa_dsac_ent05-h1",
        "my_run": "cadrl-h1",
    }


def test_combined_recipe_panels_take_its_encoders_and_crowd_sizes(tmp_path):
    for encoder in ("rg", "aw", "lsa"):
        _run(tmp_path, f"{encoder}_dsac_aln_avg-s0", f"{encoder}_dsac_aln_avg", 0, encoder=encoder)
    _run(tmp_path, "lsa_dsac_aln_avg-h2-s0", "lsa_dsac_aln_avg", 0, humans=2)
    _run(tmp_path, "lsa_dsac_aln_avg-h10-s0", "lsa_dsac_aln_avg", 0, humans=10)
    _run(tmp_path, "rg_dsac_aln_avg-h10-s0", "rg_dsac_aln_avg", 0, humans=10, encoder="rg")
    _run(tmp_path, "rg_dsac_ent05-h10-s0", "rg_dsac_ent05", 0, humans=10, encoder="rg")
    _run(tmp_path, "aw_dsac_ent05-s0", "aw_dsac_ent05", 0, encoder="aw")
    _run(tmp_path, "lsa_dsac_aln_avg_utd1-s0", "lsa_dsac_aln_avg", 0)  # a variant, not the preset
    runs = discover_runs(tmp_path)
    panels = {panel.key: panel for panel in PANELS}
    assert list(panel_lines(panels["h"], runs)) == ["AW", "LSA", "RG"]
    lines = panel_lines(panels["i"], runs)
    assert list(lines) == ["2 humans", "5 humans", "10 humans"] and len(lines["5 humans"]) == 1
    assert [r.folder.name for r in panel_lines(panels["a"], runs)["AW"]] == ["aw_dsac_ent05-s0"]
    # 10 humans: one panel per recipe, so the two RG runs are never drawn as seeds of one line
    assert [r.folder.name for r in panel_lines(panels["b"], runs)["RG"]] == ["rg_dsac_ent05-h10-s0"]
    assert list(panel_lines(panels["j"], runs)) == ["LSA", "RG"]
    assert [r.folder.name for r in panel_lines(panels["j"], runs)["RG"]] == [
        "rg_dsac_aln_avg-h10-s0"
    ]
