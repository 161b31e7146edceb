"""Packaging: version, scenario descriptions, licence metadata, run folders that stand alone."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
import yaml

import quadslam_env
from agents.lab.cli import main as cli
from quadslam_env.config.files import available_scenarios, config_dir, scenario_descriptions
from quadslam_env.config.scenario import SECTIONS, load_scenario
from quadslam_env.schema import ConfigError

ROOT = Path(__file__).resolve().parent.parent


def _pyproject() -> dict:
    tomllib = pytest.importorskip("tomllib")  # Python >= 3.11
    return tomllib.loads((ROOT / "pyproject.toml").read_text())


def test_version_is_single_sourced(capsys: pytest.CaptureFixture[str]) -> None:
    pyproject = _pyproject()
    assert "version" in pyproject["project"]["dynamic"]
    attr = pyproject["tool"]["setuptools"]["dynamic"]["version"]["attr"]
    assert attr == "quadslam_env._version.__version__"
    assert re.fullmatch(r"\d+\.\d+\.\d+", quadslam_env.__version__)
    with pytest.raises(SystemExit) as done:
        cli.main(["--version"])
    assert done.value.code == 0
    assert capsys.readouterr().out == f"quadslam {quadslam_env.__version__}\n"


def test_license_is_a_pep639_expression_with_the_mit_text() -> None:
    project = _pyproject()["project"]
    assert project["license"] == "MIT"
    assert project["license-files"] == ["LICENSE"]
    assert not any("License ::" in c for c in project.get("classifiers", []))
    text = (ROOT / "LICENSE").read_text()
    assert text.startswith("MIT License") and "WITHOUT WARRANTY OF ANY KIND" in text


def test_packages_are_the_code_folders_and_configs_ships_every_yaml() -> None:
    """The listed packages are exactly the code folders with an ``__init__.py`` and the
    folders of the top-level ``configs/`` (mapped to ``quadslam_env.configs``), and the
    package-data globs cover every file in ``configs/`` (a file the globs miss would be left
    out of the wheel)."""
    setuptools_cfg = _pyproject()["tool"]["setuptools"]
    assert setuptools_cfg["package-dir"] == {"quadslam_env.configs": "configs"}
    code = {
        ".".join(init.parent.relative_to(ROOT).parts)
        for top in ("quadslam_env", "estimators", "agents")
        for init in (ROOT / top).rglob("__init__.py")
    }
    data = {
        ".".join(("quadslam_env", *folder.relative_to(ROOT).parts))
        for folder in [ROOT / "configs", *(ROOT / "configs").rglob("*")]
        if folder.is_dir() and folder.name != "__pycache__"
    }
    assert sorted(setuptools_cfg["packages"]) == sorted(code | data)
    assert (ROOT / "configs" / "__init__.py").is_file()
    assert not (ROOT / "quadslam_env" / "configs").exists()
    globs = setuptools_cfg["package-data"]
    files = [
        p
        for p in (ROOT / "configs").rglob("*")
        if p.is_file() and "__pycache__" not in p.parts and p.name != "__init__.py"
    ]
    for path in files:
        package = ".".join(("quadslam_env", *path.parent.relative_to(ROOT).parts))
        assert any(path.match(g) for g in globs.get(package, [])), path
    assert {p.parent.name for p in files} == {"scenarios", "agents", "sweeps"}


def test_config_dir_is_the_checkout_configs_folder(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("QUADSLAM_CONFIG_DIR", raising=False)
    assert config_dir() == ROOT / "configs"
    assert sorted(p.stem for p in (ROOT / "configs" / "scenarios").glob("*.yaml")) == (
        available_scenarios()
    )


def test_every_shipped_scenario_has_a_one_line_description() -> None:
    rows = scenario_descriptions()
    assert list(rows) == available_scenarios()
    for name, text in rows.items():
        raw = yaml.safe_load((config_dir() / "scenarios" / f"{name}.yaml").read_text())
        assert text == raw["description"] and text and "\n" not in text, name
        assert load_scenario(name).description == text


def test_scenarios_command_lists_names_and_descriptions(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert cli.main(["scenarios"]) == 0
    lines = capsys.readouterr().out.splitlines()
    listed = {line.split()[0]: line.split(None, 1)[1] for line in lines[:-1]}
    assert listed == scenario_descriptions()
    assert lines[-1].startswith(f"({len(listed)} scenarios in ")


@pytest.mark.parametrize("bad", ["", "two\nlines", 3, "x" * 161])
def test_bad_description_names_the_key_and_what_is_allowed(bad: object) -> None:
    with pytest.raises(ConfigError) as err:
        load_scenario({"description": bad})
    assert str(err.value).startswith(f"description: got {bad!r}; allowed: one line of text")


@pytest.mark.parametrize("name", available_scenarios())
def test_resolved_scenario_rebuilds_the_same_config(name: str) -> None:
    cfg = load_scenario(name)
    plain = cfg.to_dict()
    assert set(plain) == {"name", "description", *SECTIONS}
    assert load_scenario(yaml.safe_load(yaml.safe_dump(plain))) == cfg


def test_evaluate_uses_the_run_folder_config_only(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """A run trained with env_kwargs overrides evaluates on the same env, without config files."""
    monkeypatch.chdir(tmp_path)
    args = ["train", "--algo", "ppo", "--env", "QuadSLAM-v0", "--timesteps", "64"]
    args += ["--n-envs", "1", "--out", "runs", "--no-progress", "--hyperparams"]
    args += ["n_steps=32", "batch_size=32", "n_epochs=1", "policy_kwargs={net_arch: [8]}"]
    args += ["env_kwargs.episode.duration_s=0.3", "eval_freq=0", "checkpoint_freq=0"]
    assert cli.main(args) == 0
    (run_dir,) = (tmp_path / "runs").glob("ppo_*")
    empty = tmp_path / "no_configs"
    empty.mkdir()
    monkeypatch.setenv("QUADSLAM_CONFIG_DIR", str(empty))
    out = tmp_path / "eval.json"
    code = cli.main(["evaluate", "--policy", str(run_dir), "--episodes", "1", "--json", str(out)])
    assert code == 0
    result = json.loads(out.read_text())
    # ppo.yaml's QuadSLAM-v0 entry: the hover scenario with thrust_rates actions.
    assert result["scenario"] == "hover"
    assert result["episodes"][0]["duration_s"] == pytest.approx(0.3)
    capsys.readouterr()
    # Another env id keeps the run's scenario but switches the estimator: said in one note.
    args = ["evaluate", "--policy", str(run_dir), "--env", "QuadSLAM-Oracle-v0"]
    assert cli.main([*args, "--episodes", "1", "--json", str(out)]) == 0
    assert "note: flying the run's scenario with QuadSLAM-Oracle-v0's estimator" in (
        capsys.readouterr().err
    )
    assert json.loads(out.read_text())["estimator"] == "oracle"


def test_citation_and_changelog_name_the_current_version() -> None:
    citation = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert str(citation["version"]) == quadslam_env.__version__
    assert citation["license"] == "MIT"
    dois = {ref["doi"] for ref in citation["references"]}
    assert dois == {"10.3390/electronics12051113", "10.1109/ACCESS.2021.3106864"}
    changelog = (ROOT / "CHANGELOG.md").read_text()
    assert f"## {quadslam_env.__version__} " in changelog


def test_readme_cites_the_papers_by_author_year_and_doi() -> None:
    readme = (ROOT / "README.md").read_text()
    assert "seed 00" not in readme.lower() and "seed-00" not in readme.lower()
    for doi in ("10.3390/electronics12051113", "10.1109/ACCESS.2021.3106864"):
        assert f"doi:[{doi}](https://doi.org/{doi})" in readme
    assert "download.pytorch.org/whl/cpu" in readme
