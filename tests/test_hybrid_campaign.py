"""Campaigns of a model with modes (bgc/experiment): a group's controlled changes of mode
(``modes:``), located errors, and runs of the relay of tests/data/hybrid/relay_rl.yaml."""

from __future__ import annotations

from pathlib import Path

import pytest

from bgc.errors import BgcError
from bgc.experiment import campaign_file, one_run

ROOT = Path(__file__).resolve().parent.parent
RELAY = ROOT / "tests" / "data" / "hybrid" / "relay_rl.yaml"
CIRCUIT = ROOT / "models" / "circuit.yaml"


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "campaign.yaml"
    path.write_text(text, encoding="utf-8")
    return path


@pytest.mark.parametrize("model, modes, words", [
    (RELAY, "shut@3", "'shut' is no mode of the model"),
    (RELAY, "closed", "'closed' is not MODE@TIME"),
    (CIRCUIT, "on@3", "has no modes"),
])
def test_a_groups_modes_that_do_not_fit_its_model_are_a_located_line(tmp_path, model, modes, words):
    path = write(tmp_path, f"campaign: bad\ngroups:\n  - name: g\n    model: {model}\n    modes: {modes}\n"
                           "    scenarios: [none]\n")
    with pytest.raises(BgcError) as err:
        campaign_file.load_campaign(path)
    assert words in str(err.value) and f"{path}:5:" in str(err.value), str(err.value)


@pytest.mark.slow
@pytest.mark.long
def test_a_campaign_runs_the_relay_through_its_switches(tmp_path):
    """Each run is simulated through the automaton with the group's trip of the supply at 6 s
    (the relay's own closings and openings besides), diagnosed with the data's mode column."""
    path = write(tmp_path, f"campaign: relay\nseed: 1\ndefaults: {{particles: [300], steps: 1000}}\ngroups:\n"
                           f"  - name: tripped\n    model: {RELAY}\n    modes: unpowered@6\n"
                           "    scenarios: [none, 'R_aux:abrupt:0.4@3']\n")
    campaign = campaign_file.load_campaign(path)
    assert [s.modes for s in campaign.specs] == ["unpowered@6"] * 2
    free, faulty = (one_run.run_one(s, backend="numpy") for s in campaign.specs)
    assert free["status"] == "ok" and free["verdict"] == "no fault", free["failure"]
    assert faulty["status"] == "ok" and faulty["right"] and faulty["est_error"] < 0.1, faulty
    assert faulty["separable"] is not None  # the prediction ran with the group's modes
