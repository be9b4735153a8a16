"""The suite's own settings: what keeps it green on a loaded machine (issue 37, item 3)."""

from __future__ import annotations

from hypothesis import HealthCheck, settings


def test_hypothesis_runs_without_deadline_in_either_profile() -> None:
    """tests/conftest.py loads the suite's profile (or CI's, which draws the same examples
    each run): no test may fail because the machine is busy."""
    assert settings._current_profile in ("tmcl-sim", "ci")  # type: ignore[attr-defined]
    for profile in ("tmcl-sim", "ci"):
        assert settings.get_profile(profile).deadline is None
        assert HealthCheck.too_slow in settings.get_profile(profile).suppress_health_check
    assert settings.get_profile("ci").derandomize and settings.get_profile("ci").database is None
