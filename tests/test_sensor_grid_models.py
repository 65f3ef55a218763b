"""The sensor-fault grid (experiments/sensor_grid.yaml) runs on variants of
the shipped models that declare every sensor and actuator fault kind: they
must stay the shipped plants (only the name and the faults section differ),
declare every kind the fault-kind table gives a sensor and an actuator, and
the grid must try every sensor kind on a sensor of each plant and every
actuator kind on every input, at both noise levels with 20 seeds."""

from __future__ import annotations

import pytest
import yaml


from bgc.experiment import campaign_file
from bgc.kinds import FAULT_KINDS

from conftest import ROOT

SENSOR_KINDS = [k for k, fk in FAULT_KINDS.items() if "sensor" in fk.targets]
ACTUATOR_KINDS = [k for k, fk in FAULT_KINDS.items() if "actuator" in fk.targets]


def _load(path):
    return yaml.safe_load(path.read_text(encoding="utf-8"))


@pytest.mark.parametrize("plant", ["circuit", "two_tank", "ro"])
def test_a_variant_is_its_shipped_plant_with_every_sensor_and_actuator_kind(plant):
    shipped = _load(ROOT / "models" / f"{plant}.yaml")
    variant = _load(ROOT / "experiments" / "models" / f"{plant}_all_kinds.yaml")
    assert variant["name"] == shipped["name"] + "_all_kinds"
    assert {k: v for k, v in variant.items() if k not in ("name", "faults")} == \
        {k: v for k, v in shipped.items() if k not in ("name", "faults")}
    sensors, inputs = set(shipped["measurements"]), set(shipped["inputs"])
    # the parameter faults are the shipped ones, untouched
    assert {k: v for k, v in variant["faults"].items() if k not in sensors | inputs} == \
        {k: v for k, v in shipped["faults"].items() if k not in sensors | inputs}
    for s in sensors:
        assert variant["faults"][s]["kinds"] == SENSOR_KINDS, s
    for u in inputs:
        assert variant["faults"][u]["kinds"] == ACTUATOR_KINDS, u


@pytest.mark.slow
def test_the_grid_tries_every_kind_on_a_sensor_of_each_plant_and_on_every_input_at_both_noise_levels_with_20_seeds():
    grid = campaign_file.load_campaign(ROOT / "experiments" / "sensor_grid.yaml")
    cells: dict[tuple, set] = {}
    for s in grid.specs:
        subject = s.scenario.split(":")[0] if s.fault else None  # f2:bias:0.5@7.5 -> f2
        cells.setdefault((s.model_name, subject, s.kind), set()).add((s.noise, s.seed))
    for plant in ("circuit", "two_tank", "ro"):
        shipped = _load(ROOT / "models" / f"{plant}.yaml")
        name = plant + "_all_kinds"
        tried = {c for c in cells if c[0] == name and c[1] is not None}
        sensors = {c[1] for c in tried if c[1] in shipped["measurements"]}
        assert sensors, plant
        wanted = {(name, s, k) for s in sensors for k in SENSOR_KINDS} | \
                 {(name, u, k) for u in shipped["inputs"] for k in ACTUATOR_KINDS}
        assert tried == wanted, plant
        for c in wanted:
            assert len({n for n, _ in cells[c]}) == 2 and len(cells[c]) == 40, c
        assert len(cells[(name, None, None)]) == 40
