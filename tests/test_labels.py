"""Labels: each variable's meaning and unit from the model. The expected
texts are read from the YAML files here (with yaml, not bgc), so a label that
lost its unit, its element or its meaning fails."""

import textwrap

import yaml

from bgc.compiler.load import load, loads
from bgc.compiler.validate import validate
from bgc.kinds import DOMAINS
from bgc.output.labels import Labels, labels_of

from conftest import ALL_MODELS, MODELS


def _yaml(name: str) -> dict:
    return yaml.safe_load((MODELS / f"{name}.yaml").read_text())


def test_a_state_is_named_by_its_element_its_domain_and_the_unit_its_source_imposes():
    doc = _yaml("circuit")
    kind = {n: str(e["kind"]) for n, e in doc["elements"].items()}
    (source,) = [n for n, k in kind.items() if k == "Se"]
    unit = doc["inputs"][doc["elements"][source].get("value", source)]["unit"]
    # the C elements junctions join to the source (no two-port in between): their efforts are in its unit
    seen, todo, caps = {source}, [source], []
    while todo:
        here = todo.pop()
        for k, ends in doc["bonds"].items():
            if here in ends:
                (other,) = [e for e in ends if e != here]
                if kind[other] in ("0", "1") and other not in seen:
                    seen.add(other)
                    todo.append(other)
                elif kind[other] == "C":
                    caps.append((other, k))
    assert caps
    labels = labels_of(validate(load(str(MODELS / "circuit.yaml"))))
    for cap, bond in caps:
        assert labels.axis(f"e{bond}") == f"e{bond}: {DOMAINS[doc['domain']].effort} at {cap} [{unit}]"


def test_ro_states_say_their_element_and_meaning_and_no_unit_the_model_does_not_declare():
    doc = _yaml("ro")
    declared = [s for section in ("parameters", "inputs", "measurements") for s in doc[section].values()
                if isinstance(s, dict) and "unit" in s]
    assert not declared  # the thesis's scaled units: none is declared
    labels = labels_of(validate(load(str(MODELS / "ro.yaml"))))
    for element, spec in doc["elements"].items():
        if spec["kind"] not in ("C", "I"):
            continue
        bond = next(k for k, ends in doc["bonds"].items() if element in ends)
        domain = DOMAINS[doc["domain"]]
        name = f"{'e' if spec['kind'] == 'C' else 'f'}{bond}"
        meaning = spec.get("quantity") or (domain.effort if spec["kind"] == "C" else domain.flow)
        assert labels.axis(name) == f"{name}: {meaning} {'at' if spec['kind'] == 'C' else 'through'} {element}"
    assert labels.time == f"time [{doc['simulation']['time_unit']}]"


def test_measurements_parameters_and_inputs_carry_their_declared_units():
    doc = _yaml("two_tank")
    labels = labels_of(validate(load(str(MODELS / "two_tank.yaml"))))
    for section in ("parameters", "inputs", "measurements"):
        for name, spec in doc[section].items():
            unit = spec.get("unit") if isinstance(spec, dict) else None
            assert labels.axis(name) == (f"{name} [{unit}]" if unit else name)


def test_every_model_is_labelled_and_none_shows_an_empty_unit():
    for path in ALL_MODELS.values():
        labels = labels_of(validate(load(str(path))))
        for name, _ in (*labels.units, *labels.meanings):
            assert "[None]" not in labels.axis(name) and "[]" not in labels.axis(name)


BARE = """\
name: m
parameters: {R: 1.0, C: 2.0, m: 3.0, C2: 1.0}
inputs: {Vs: {value: 1.0, unit: V}}
elements:
  Vs: {kind: Se}
  j: {kind: "1"}
  R: {kind: R}
  C: {kind: C}
  TF: {kind: TF, parameter: m}
  k: {kind: "0"}
  C2: {kind: C}
bonds:
  1: [Vs, j]
  2: [j, R]
  3: [j, C]
  4: [j, TF]
  5: [TF, k]
  6: [k, C2]
measurements:
  P: {expr: e3, unit: V}
  y6: {expr: e6}
"""


def build(text: str):
    return labels_of(validate(loads(textwrap.dedent(text), "m.yaml")))


def test_a_unit_stops_at_a_transformer_and_without_declarations_nothing_is_bracketed():
    labels = build(BARE)
    assert labels.axis("e3") == "e3: effort at C [V]"
    assert labels.axis("e6") == "e6: effort at C2"      # beyond TF: its modulus may change the unit
    assert labels.time == "time" and labels.per_time == "per unit time"


def test_two_units_declared_in_one_part_give_none():
    labels = build(BARE.replace("P: {expr: e3, unit: V}", "P: {expr: e3, unit: kV}"))
    assert (labels.axis("e3"), labels.axis("P")) == ("e3: effort at C", "P [kV]")
    assert build(BARE.replace("  y6: {expr: e6}", "  y2: {expr: e2, unit: V}")).unit("e3") == "V"
    assert build(BARE.replace("  y6: {expr: e6}", "  y2: {expr: e2, unit: mV}")).unit("e3") is None


def test_a_drift_s_unit_is_per_unit_of_time():
    assert Labels(time_unit="s").magnitude_unit("ohm", drifts=True) == "ohm/s"
    assert Labels(time_unit="s").magnitude_unit("ohm", drifts=False) == "ohm"
    assert Labels().magnitude_unit("ohm", drifts=True) == "ohm per unit time"
    assert Labels(time_unit="h").magnitude_unit(None, drifts=True) == "per h"
    assert Labels().magnitude_unit(None, drifts=True) is None
