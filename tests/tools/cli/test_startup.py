"""The command line starts without its heavy libraries; the scenario list is read from the files'
headlines; a bad-input error is still one line, whichever module raised it."""

from __future__ import annotations

import subprocess
import sys

import pytest
import typer
import yaml

from boomtip.tools.cli.common import user_error_types, user_errors
from boomtip.tools.config.catalog import available_scenarios, scenario_headline

HEAVY = ("numpy", "scipy", "open3d", "boomtip.tools.config.scenario", "boomtip.tools.chains.runner")


def _loaded_after(code: str) -> set[str]:
    probe = f"import sys\n{code}\nprint('LOADED', *(m for m in {HEAVY!r} if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", probe], check=True, capture_output=True, text=True).stdout
    return set(out.splitlines()[-1].split()[1:])


def test_the_command_line_and_its_help_load_no_heavy_library():
    assert _loaded_after("import boomtip.tools.cli.commands") == set()
    code = "from boomtip.tools.cli import main\nsys.argv = ['boomtip', '--help']\ntry:\n    main()\nexcept SystemExit:\n    pass"
    assert _loaded_after(code) == set()


def test_listing_the_scenarios_loads_no_model():
    code = ("from boomtip.tools.cli import main\nsys.argv = ['boomtip', 'scenarios']\ntry:\n    main()\n"
            "except SystemExit:\n    pass")
    assert _loaded_after(code) == set()


def test_every_built_in_headline_agrees_with_the_full_model():
    from boomtip.tools.config.scenario import load_scenario

    for name, path in available_scenarios().items():
        s = load_scenario(path)
        headline = scenario_headline(path)
        assert headline == (s.duration_s, s.description), name


def test_a_file_that_leaves_the_duration_to_the_defaults_has_no_headline(tmp_path):
    p = tmp_path / "s.yaml"
    p.write_text(yaml.safe_dump({"description": "x"}))
    assert scenario_headline(p) is None
    p.write_text("- a list\n")
    assert scenario_headline(p) is None


def test_a_scenario_error_is_one_line_and_exit_2_once_its_module_is_loaded(capsys):
    from boomtip.tools.config.scenario import ScenarioError

    assert ScenarioError in user_error_types()
    with pytest.raises(typer.Exit) as exc:
        with user_errors():
            raise ScenarioError("scenario key 'x': unknown")
    assert exc.value.exit_code == 2
    assert "scenario key 'x': unknown" in capsys.readouterr().err


def test_an_unexpected_error_is_not_swallowed():
    with pytest.raises(ZeroDivisionError):
        with user_errors():
            1 / 0
