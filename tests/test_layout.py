"""The bond graph layout: deterministic, and readable in the obvious ways
(no label box on another, no bond through a box it does not end at), on
every model the stage tests use."""

import pytest

from bgc.output.layout import bond_graph_layout, boxes_overlap, label, label_size, segment_hits_box, signal_links
from bgc.pipeline import assign_causality

from conftest import ALL_MODELS


@pytest.fixture(scope="module", params=sorted(ALL_MODELS))
def model(request):
    return assign_causality(ALL_MODELS[request.param]).model


def test_every_element_has_a_place_and_the_same_one_twice(model):
    lay = bond_graph_layout(model)
    assert sorted(n for n, _, _ in lay.positions) == sorted(el.name for el in model.elements)
    assert bond_graph_layout(model) == lay


def test_no_label_box_overlaps_another(model):
    lay = bond_graph_layout(model)
    boxes = {el.name: (*lay.at(el.name), *label_size(label(el))) for el in model.elements}
    names = sorted(boxes)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            assert not boxes_overlap(boxes[a], boxes[b], 0.05), (a, b)


def test_no_bond_runs_through_an_element_it_does_not_join(model):
    lay = bond_graph_layout(model)
    boxes = {el.name: (*lay.at(el.name), *label_size(label(el))) for el in model.elements}
    for b in model.bonds:
        for name, box in boxes.items():
            if name not in (b.tail, b.head):
                assert not segment_hits_box(lay.at(b.tail), lay.at(b.head), box), (b.number, name)


def test_signal_links_are_read_from_the_modulated_elements():
    ro = assign_causality(ALL_MODELS["ro"]).model
    # MR_memb's parameter reads e27; MSf_k's value reads f10 and f18 (models/ro.yaml)
    assert signal_links(ro) == ((10, "MSf_k"), (18, "MSf_k"), (27, "MR_memb"))
