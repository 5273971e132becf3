"""One model card schema (zoo/train/card.schema.json, JSON Schema): every shipped card passes it, a
drifted card does not, and what the card says about the weights is what the weights are."""

from __future__ import annotations

import copy
import json

import jsonschema
import pytest

from overtakezoo import zoo
from overtakezoo.zoo.members.learned import PRETRAINED, load_weights
from overtakezoo.zoo.train.contract import CARD_SCHEMA, card_errors, check_card

SCHEMA = json.loads(CARD_SCHEMA.read_text())
SHIPPED = sorted(p.stem for p in PRETRAINED.glob("*.json"))


def test_the_schema_is_a_valid_json_schema():
    jsonschema.Draft202012Validator.check_schema(SCHEMA)


def test_every_learned_member_ships_a_card_and_every_card_is_a_learned_member():
    assert SHIPPED == zoo.names("learned")


@pytest.mark.parametrize("name", SHIPPED)
def test_every_shipped_card_passes_the_schema(name):
    card = json.loads((PRETRAINED / f"{name}.json").read_text())
    jsonschema.validate(card, SCHEMA, cls=jsonschema.Draft202012Validator)
    assert card["name"] == name
    net = load_weights(PRETRAINED / card["weights_file"], card, name)  # the sha256 matches
    arch = card["architecture"]
    assert arch["layers"] == [list(w.shape) for w, _ in net.layers] and arch["dueling"] == net.dueling
    assert card["weights_bytes"] == (PRETRAINED / card["weights_file"]).stat().st_size
    kind = zoo.load(name).model_card["architecture"]["kind"]
    assert kind == {"ppo": "policy", "bc": "classifier", "dagger": "classifier"}.get(name, "q-network")


def _dqn_card():
    return json.loads((PRETRAINED / "dqn.json").read_text())


@pytest.mark.parametrize(
    "drift, needle",
    [
        (lambda c: c.update(train_suite="core-train"), "train_suite: 'core-train' is not of type 'object'"),
        (lambda c: c.update(torch="2.13.0"), "'torch' was unexpected"),
        (lambda c: c.pop("steps_unit"), "'steps_unit' is a required property"),
        (lambda c: c.pop("action_mask_version"), "'action_mask_version' is a required property"),
        (lambda c: c.update(dataset={"name": "x"}), "exactly one of train_suite (with training_reward) and dataset"),
        (lambda c: c["architecture"].update(kind="classfier"), "architecture.kind: 'classfier' is not one of"),
        (lambda c: c["results"]["table1"].pop("suite_sha256"), "'suite_sha256' is a required property"),
        (lambda c: c.update(weights_sha256="abc"), "weights_sha256: 'abc' does not match"),
    ],
)
def test_a_drifted_card_is_refused_naming_the_key(drift, needle):
    card = _dqn_card()
    assert card_errors(card) == []
    bad = copy.deepcopy(card)
    drift(bad)
    errors = card_errors(bad)
    assert any(needle in e for e in errors), errors
    with pytest.raises(ValueError, match="model card"):
        check_card(bad)
