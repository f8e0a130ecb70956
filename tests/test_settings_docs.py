"""Every setting has a description and is documented; environment and flags both reach Settings."""

from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import ValidationError

from sdfserver.api.server import parser, settings_from
from sdfserver.settings import Settings, unknown_environment

DOC = (Path(__file__).resolve().parents[1] / "docs" / "configuration.md").read_text()


@pytest.mark.parametrize("name", sorted(Settings.model_fields))
def test_every_setting_is_described_and_documented(name):
    field = Settings.model_fields[name]
    assert field.description and len(field.description) > 10, f"{name} needs a description"
    assert f"`{name}`" in DOC, f"{name} is missing from docs/configuration.md"
    assert f"`SDFSERVER_{name.upper()}`" in DOC
    assert f"`--{name.replace('_', '-')}`" in DOC
    assert f"--{name.replace('_', '-')}" in parser().format_help()


def test_documented_settings_exist():
    import re

    documented = set(re.findall(r"^\| `([a-z_]+)` \|", DOC, flags=re.M))
    assert documented == set(Settings.model_fields)


def test_environment_then_flags(monkeypatch):
    monkeypatch.setenv("SDFSERVER_PORT", "9123")
    monkeypatch.setenv("SDFSERVER_MAX_OPS_PER_BATCH", "7")
    monkeypatch.setenv("SDFSERVER_WARM_UP", "false")
    s = settings_from(["--max-ops-per-batch", "9", "--log-format", "json"])
    assert (s.port, s.max_ops_per_batch, s.log_format, s.warm_up) == (9123, 9, "json", False)
    assert s.edit_limits().max_ops_per_batch == 9
    assert settings_from(["--warm-up"]).warm_up is True
    with pytest.raises(ValidationError):
        settings_from(["--port", "70000"])
    with pytest.raises(SystemExit):
        settings_from(["--log-format", "xml"])


def test_unknown_environment_variables_are_named_with_the_likely_setting():
    environ = {"SDFSERVER_MAX_REQEUST_BYTES": "1", "sdfserver_data_dir": "x", "SDFSERVER_PORT": "1",
               "SDFSERVER_COLOUR": "red", "SDFSERVER_API_KEY": "k" * 16, "HOME": "/", "PYTEST_SDFSERVER_X": "1"}
    lines = unknown_environment(environ)
    assert len(lines) == 2, lines
    colour, request = lines
    assert colour.startswith("SDFSERVER_COLOUR ") and "docs/configuration.md" in colour
    assert request.startswith("SDFSERVER_MAX_REQEUST_BYTES ") and "SDFSERVER_MAX_REQUEST_BYTES?" in request
    assert unknown_environment({f"SDFSERVER_{name.upper()}": "" for name in Settings.model_fields}) == []


def test_serve_warns_of_an_unknown_variable_at_start(tmp_path):
    from server_process import ServerProcess

    server = ServerProcess(tmp_path / "data", "--no-warm-up", "--workers", "1",
                           env={"SDFSERVER_MAX_WORLD_VOXEL": "512"})
    try:
        server.wait_ready()
    finally:
        server.stop()
    warnings = [line for line in server.output().splitlines() if "SDFSERVER_MAX_WORLD_VOXEL " in line]
    assert len(warnings) == 1 and "WARNING" in warnings[0], server.output()
    assert "did you mean SDFSERVER_MAX_WORLD_VOXELS?" in warnings[0]
