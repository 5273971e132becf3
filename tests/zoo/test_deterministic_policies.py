"""A policy is deterministic or refused (issue 35): an ONNX graph with a random op, or a policy whose
decisions depend on the batch (its size, its row order) or on the calls before, passes a full re-run
and then fails every later sampled verification; `submit` and a full `leaderboard --verify` refuse it."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest

from conftest import last_error_line
from overtakezoo.benchmark.cli import main
from overtakezoo.benchmark.results.results import Results
from overtakezoo.benchmark.run.determinism import random_ops
from overtakezoo.envs import EnvConfig, observation_size

onnx = pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")
from onnx import TensorProto, helper, numpy_helper  # noqa: E402

D = observation_size(EnvConfig())


def _model(nodes=(), inits=(), out="scores", opset=17, functions=()):
    """An ONNX MLP layer (N, D) -> 3 scores (seeded weights), then ``nodes`` computing ``out``."""
    rng = np.random.default_rng(0)
    weights = [
        numpy_helper.from_array(rng.normal(size=(D, 3)).astype(np.float32), "w"),
        numpy_helper.from_array(rng.normal(size=3).astype(np.float32), "b"),
    ]
    graph = helper.make_graph(
        [helper.make_node("MatMul", ["obs", "w"], ["xw"]), helper.make_node("Add", ["xw", "b"], ["scores"]), *nodes],
        "policy",
        [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["N", D])],
        [helper.make_tensor_value_info(out, TensorProto.FLOAT, ["N", 3])],
        initializer=[*weights, *inits],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", opset)], functions=list(functions))
    model.ir_version = 8
    return model


def _save(model, path):
    onnx.checker.check_model(model)
    onnx.save_model(model, str(path))
    return path


def _bool(name, value):
    return numpy_helper.from_array(np.array(value), name)


def HONEST():
    return _model([helper.make_node("Dropout", ["scores"], ["out"], name="inference-dropout")], out="out")


# Scores minus their mean over the batch axis: the decision for a row depends on the other rows.
def BATCH():
    return _model(
        [
            helper.make_node("ReduceMean", ["scores"], ["mean"], axes=[0], keepdims=1),
            helper.make_node("Sub", ["scores", "mean"], ["out"]),
        ],
        out="out",
    )


# Seeded noise: a fresh session draws the same sequence, so a full re-run reproduces the run it follows.
def RANDOM():
    return _model(
        [
            helper.make_node("RandomUniform", [], ["noise"], name="noise", shape=[1, 3], low=0.0, high=10.0, seed=1.0),
            helper.make_node("Add", ["scores", "noise"], ["out"]),
        ],
        out="out",
    )


def _eval(tmp_path, suite, policy, out):
    assert main(["eval", "--policy", str(policy), "--suite", suite, "--out", str(tmp_path / out), "--no-progress"]) == 0
    return tmp_path / out


# ------------------------------------------------------------------ the graph: random ops, named
def test_random_ops_are_found_in_graphs_subgraphs_and_functions():
    assert random_ops(HONEST().SerializeToString()) == []
    assert random_ops(BATCH().SerializeToString()) == []  # deterministic per call: the probe catches it
    assert random_ops(RANDOM().SerializeToString()) == ["RandomUniform (node 'noise')"]
    for op in ("RandomNormalLike", "RandomUniformLike", "Bernoulli"):
        m = _model([helper.make_node(op, ["scores"], ["out"])], out="out", opset=17)
        assert random_ops(m.SerializeToString()) == [op]
    m = _model([helper.make_node("Multinomial", ["scores"], ["out"], sample_size=3)], out="out")
    assert random_ops(m.SerializeToString()) == ["Multinomial"]
    m = _model([helper.make_node("RandomNormal", [], ["out"], shape=[1, 3])], out="out")
    assert random_ops(m.SerializeToString()) == ["RandomNormal"]

    # Dropout: random only when its training_mode may be true.
    def drop(*inputs):
        return _model(
            [helper.make_node("Dropout", ["scores", *inputs], ["out"])],
            out="out",
            inits=[numpy_helper.from_array(np.array(0.5, np.float32), "ratio"), _bool("off", False), _bool("on", True)],
        )

    assert random_ops(drop().SerializeToString()) == []
    assert random_ops(drop("ratio").SerializeToString()) == []
    assert random_ops(drop("ratio", "").SerializeToString()) == []
    assert random_ops(drop("ratio", "off").SerializeToString()) == []
    assert random_ops(drop("ratio", "on").SerializeToString()) == ["Dropout"]
    const = _model(
        [
            helper.make_node("Constant", [], ["t"], value=_bool("v", True)),
            helper.make_node("Dropout", ["scores", "", "t"], ["out"]),
        ],
        out="out",
    )
    assert random_ops(const.SerializeToString()) == ["Dropout"]
    fed = _model([helper.make_node("Dropout", ["scores", "", "train"], ["out"])], out="out")
    fed.graph.input.append(helper.make_tensor_value_info("train", TensorProto.BOOL, []))  # the caller may feed true
    assert random_ops(fed.SerializeToString()) == ["Dropout"]
    old = _model([helper.make_node("Dropout", ["scores"], ["out"])], out="out", opset=6)  # is_test 0: training
    assert random_ops(old.SerializeToString()) == ["Dropout"]
    old = _model([helper.make_node("Dropout", ["scores"], ["out"], is_test=1)], out="out", opset=6)
    assert random_ops(old.SerializeToString()) == []

    # Inside an If branch, inside a model-local function, and a contrib op of another domain.
    branch = helper.make_graph(
        [helper.make_node("RandomNormalLike", ["scores"], ["r"], name="deep")],
        "then",
        [],
        [helper.make_tensor_value_info("r", TensorProto.FLOAT, None)],
    )
    plain = helper.make_graph(
        [helper.make_node("Identity", ["scores"], ["r2"])],
        "else",
        [],
        [helper.make_tensor_value_info("r2", TensorProto.FLOAT, None)],
    )
    m = _model(
        [
            helper.make_node("Constant", [], ["c"], value=_bool("cv", True)),
            helper.make_node("If", ["c"], ["out"], then_branch=branch, else_branch=plain),
        ],
        out="out",
    )
    assert random_ops(m.SerializeToString()) == ["RandomNormalLike (node 'deep')"]
    fn = helper.make_function(
        "mine", "Noisy", ["x"], ["y"], [helper.make_node("Bernoulli", ["x"], ["y"])], [helper.make_opsetid("", 17)]
    )
    m = _model([helper.make_node("Noisy", ["scores"], ["out"], domain="mine")], out="out", functions=[fn])
    assert random_ops(m.SerializeToString()) == ["Bernoulli"]
    m = _model([helper.make_node("BiasDropout", ["scores"], ["out"], domain="com.microsoft")], out="out")
    assert random_ops(m.SerializeToString()) == ["com.microsoft.BiasDropout"]


# ------------------------------------------------------------------ submit
def test_submit_refuses_a_random_op_naming_it(tiny, tmp_path, capsys):
    policy = _save(RANDOM(), tmp_path / "noisy.onnx")
    results = _eval(tmp_path, tiny, policy, "noisy.json")
    err = last_error_line(
        capsys, ["submit", str(results), "--policy", str(policy), "--name", "noisy", "--root", str(tmp_path / "lb")]
    )
    assert f"--policy {policy}: the ONNX graph uses the random op RandomUniform (node 'noise')" in err
    assert not (tmp_path / "lb" / "submissions" / tiny / "noisy.json").exists()


def test_submit_refuses_a_batch_dependent_policy_and_files_an_honest_one(tiny, tmp_path, capsys):
    root = tmp_path / "lb"
    policy = _save(BATCH(), tmp_path / "batchy.onnx")
    results = _eval(tmp_path, tiny, policy, "batchy.json")  # its own run: one batch of 12, reproduced as such
    err = last_error_line(
        capsys, ["submit", str(results), "--policy", str(policy), "--name", "batchy", "--root", str(root)]
    )
    assert f"--policy {policy}: not deterministic: observation " in err and "decide each observation" in err
    assert not (root / "submissions" / tiny / "batchy.json").exists()

    honest = _save(HONEST(), tmp_path / "honest.onnx")  # (an inference-mode Dropout is no random op)
    results = _eval(tmp_path, tiny, honest, "honest.json")
    assert main(["submit", str(results), "--policy", str(honest), "--name", "honest", "--root", str(root)]) == 0
    assert main(["leaderboard", "--root", str(root), "--verify", "--sample", "3", "--seed", "1"]) == 0


# ------------------------------------------------------------------ verify: a row a pull request writes itself
def _direct_row(root, suite, name, results, model: bytes):
    """An ONNX row as a hostile pull request writes it (no `submit`), labels as verify derives them."""
    sha = hashlib.sha256(model).hexdigest()
    (root / "submissions" / "artifacts").mkdir(parents=True, exist_ok=True)
    (root / "submissions" / "artifacts" / f"{sha}.onnx").write_bytes(model)
    decider = {
        "name": name,
        "version": "1",
        "weights_sha256": sha,
        "privileged": False,
        "policy": {"kind": "onnx", "file": f"{sha}.onnx", "sha256": sha},
    }
    doc = {
        **results.to_dict(),
        "decider": decider,
        "submission": {"name": name, "policy": {"artifact": f"artifacts/{sha}.onnx", "sha256": sha}},
    }
    path = root / "submissions" / suite / f"{name}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc))
    return path


@pytest.mark.parametrize(
    "make, says",
    [(BATCH, "not deterministic: observation "), (RANDOM, "uses the random op RandomUniform (node 'noise')")],
    ids=["batch-dependent", "random-op"],
)
def test_verify_refuses_a_planted_row_whose_policy_is_not_deterministic(tiny, tmp_path, capsys, make, says):
    policy = _save(make(), tmp_path / "p.onnx")
    results = Results.load(_eval(tmp_path, tiny, policy, "r.json"))
    root = tmp_path / "lb"
    _direct_row(root, tiny, "planted", results, policy.read_bytes())
    # (no git base here: every row counts as new, re-run in full, which alone would reproduce it)
    err = last_error_line(capsys, ["leaderboard", "--root", str(root), "--verify"])
    assert err.startswith(f"error: submissions/{tiny}/planted.json") and says in err
