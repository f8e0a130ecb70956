"""Every setting has a description and is documented; environment and flags both reach Settings."""

from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import ValidationError

from sdfserver.api.server import parser, settings_from
from sdfserver.settings import Settings

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
