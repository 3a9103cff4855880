"""The experiments' checkpoint cache key names the code and version that trained the network."""

from __future__ import annotations

import pytest

from experiments import common
from experiments.common import Settings, checkpoint_path, code_version, load
from vprsnn_export.version import __version__


@pytest.fixture
def keyed(tmp_path, monkeypatch):
    monkeypatch.setenv("VPRSNN_CACHE", str(tmp_path / "cache"))
    settings = Settings.quick_settings()
    cfg = settings.config(1)
    data = load(settings, "consecutive", cfg)
    return lambda: checkpoint_path(settings, data, cfg, "consecutive")


def test_key_lives_in_the_cache_folder_and_is_stable(keyed, tmp_path):
    assert keyed().parent == tmp_path / "cache"
    assert keyed() == keyed()
    assert code_version().startswith(__version__ + "+")


def test_a_source_change_changes_the_key(keyed, monkeypatch):
    before = keyed()
    monkeypatch.setattr(common, "source_fingerprint", lambda roots: "0" * 64)
    assert keyed() != before


def test_a_version_change_changes_the_key(keyed, monkeypatch):
    before = keyed()
    monkeypatch.setattr(common, "__version__", "9.9.9")
    assert keyed() != before
