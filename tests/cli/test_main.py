"""``neuenh`` itself: every command is listed and parses its own arguments, and the answers that
need no command (``--help``, ``--version``) come without importing any command's module — most of
them import torch, ~1.5 s a process."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from cli_runs import neuenh_here, run_probing_torch
from neuenh_service.cli.main import COMMANDS


@pytest.mark.parametrize("flag", ["--help", "--version"])
def test_help_and_version_answer_without_importing_torch(flag):
    out, imported_torch = run_probing_torch("neuenh_service.cli.main", flag)
    assert out.returncode == 0 and not imported_torch, out.stderr
    if flag == "--version":
        assert out.stdout.startswith("neuenh ") and out.stdout.split()[1][0].isdigit()
    else:
        for name, summary in COMMANDS.items():
            assert f"{name}  " in out.stdout and summary in " ".join(out.stdout.split()), name


@pytest.mark.parametrize("name", COMMANDS)
def test_every_command_parses_its_own_arguments(name):
    done = neuenh_here(name, "--help")
    assert done.returncode == 0, done.stderr
    usage = " ".join(done.stdout.split())
    bare = f"usage: neuenh {name} [-h] options: -h, --help show this help message and exit"  # a parser left empty
    assert usage.startswith(f"usage: neuenh {name} [-h] ") and usage != bare and "options:" in usage


# No command's --help imports torch: each imports its science where it runs (fit's help names the
# models and capacities, encoder's its default steps: written out, with tests that keep them equal).
@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_a_commands_help_needs_no_torch(name):
    out, imported_torch = run_probing_torch("neuenh_service.cli.main", name, "--help")
    assert out.returncode == 0 and f"usage: neuenh {name}" in out.stdout, out.stderr
    assert not imported_torch, f"neuenh {name} --help imported torch"


def test_an_unknown_command_is_a_usage_error_naming_the_commands():
    done = neuenh_here("fitt", "a.npz")
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert "invalid choice: 'fitt'" in done.stderr and all(repr(name) in done.stderr for name in COMMANDS)


EXAMPLE_SCENE = Path(__file__).resolve().parents[2] / "examples" / "scene.yaml"
QUICKSTART = EXAMPLE_SCENE.with_name("quickstart.yaml")


@pytest.fixture
def table(tmp_path):
    """A small measurement table (20 pairs of a grey Lambertian)."""
    from neuenh.data.directions import sample_directions
    from neuenh.data.table import write_table

    wi, wo = sample_directions(20, seed=0)
    return write_table(tmp_path / "t.npz", wi, wo, torch.full((20, 3), 0.1))


@pytest.mark.parametrize("command, flag", [
    (["fit", "--model", "ggx", "TABLE"], "-o"),
    (["export", "ggx", "--format", "glsl"], "-o"),
    (["render", "--model", "ggx"], "-o"),
    (["scene", "plan", EXAMPLE_SCENE], "-o"),
    (["search", QUICKSTART], "--out"),
    (["search", QUICKSTART], "--data-dir"),
    (["report"], "--out"),
    (["report"], "--work-dir"),
], ids=["fit", "export", "render", "scene-plan", "search-out", "search-data-dir", "report-out", "report-work-dir"])
def test_an_output_folder_that_is_a_file_is_refused_before_any_work(command, flag, table, tmp_path):
    """An output folder naming an existing file: one line, exit 2, the file untouched — before the fit,
    the export, the plan, the search or the report runs (each ended in a traceback, most after their
    work: the report's after hours of it)."""
    taken = tmp_path / "taken.json"
    taken.write_text("{}")
    out = neuenh_here(*[table if a == "TABLE" else a for a in command], flag, taken)
    assert out.returncode == 2 and "Traceback" not in out.stderr, out.stderr
    assert f"{flag} {taken}: exists and is not a folder" in out.stderr and out.stderr.count("\n") == 1, out.stderr
    assert taken.read_text() == "{}"


def test_fit_tells_a_bundle_folder_from_the_json_report(table, tmp_path):
    out = neuenh_here("fit", "--model", "ggx", table, "-o", tmp_path / "fit.json")
    assert out.returncode == 2 and f"--json > {tmp_path / 'fit.json'}" in out.stderr, out.stderr
    assert not (tmp_path / "fit.json").exists()
