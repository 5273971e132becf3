"""Issue 36's smaller defects, each now one clear `error:` line or the right output: `card` on a results
file, `decision-map --out map.jpg`, an ONNX policy with the wrong number of outputs, `gymnasium.make` of a
multi-AV suite id, and `dataset download` without minari. (SuperSuit + SB3's seeding:
tests/envs/test_pettingzoo_multi.py::test_parameter_sharing_ppo_on_supersuit_vector.)"""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest
from test_benchmark_cli import one_line_error, small_suite_file

from overtakezoo.benchmark.cli import main
from overtakezoo.envs import EnvConfig, observation_size

D = observation_size(EnvConfig())


# ------------------------------------------------------------------ card: a results file is no policy
def test_card_refuses_a_results_file(tmp_path, capsys):
    suite = small_suite_file(tmp_path, count=2)
    results = tmp_path / "r.json"
    assert (
        main(["eval", "--suite", str(suite), "--decider", "always-follow", "--out", str(results), "--no-progress"]) == 0
    )
    capsys.readouterr()
    before = results.read_bytes()
    err = one_line_error(capsys, ["card", str(results), "--action-repeat", "10"])
    assert "a results file" in err and "not a policy file" in err, err
    assert not (tmp_path / "r.card.json").exists() and results.read_bytes() == before
    # Any other JSON or text is no policy file either (a policy is a zip or an ONNX model).
    (tmp_path / "notes.json").write_text(json.dumps({"action_repeat": 10}))
    assert "a JSON file" in one_line_error(capsys, ["card", str(tmp_path / "notes.json"), "--action-repeat", "10"])
    (tmp_path / "policy.pt").write_text("not a policy\n")
    assert "not a policy file" in one_line_error(capsys, ["card", str(tmp_path / "policy.pt"), "--action-repeat", "1"])
    assert not list(tmp_path.glob("*.card.json"))


# ------------------------------------------------------------------ decision-map: the suffix's format
MAGIC = {
    ".png": b"\x89PNG\r\n\x1a\n",
    ".jpg": b"\xff\xd8\xff",
    ".jpeg": b"\xff\xd8\xff",
    ".svg": b"<?xml",
    ".pdf": b"%PDF-",
}


def test_decision_map_writes_the_format_its_suffix_names(tmp_path, capsys):
    for suffix, magic in MAGIC.items():
        out = tmp_path / f"map{suffix}"
        assert main(["decision-map", "--decider", "always-overtake", "--resolution", "3", "--out", str(out)]) == 0
        assert out.read_bytes().startswith(magic), (suffix, out.read_bytes()[:8])
    capsys.readouterr()
    err = one_line_error(
        capsys,
        ["decision-map", "--decider", "always-overtake", "--resolution", "3", "--out", str(tmp_path / "map.gif")],
    )
    assert "map.gif" in err and ".png, .jpg, .jpeg, .svg, .pdf" in err, err
    assert not (tmp_path / "map.gif").exists()


# ------------------------------------------------------------------ ONNX: the output is wrong, not the input
def _onnx_matmul(path, inputs: int, outputs: int):
    """An ONNX model obs (n, inputs) -> obs @ W (n, outputs), built with onnx.helper."""
    onnx = pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    from onnx import TensorProto, helper, numpy_helper

    w = numpy_helper.from_array(np.linspace(-1, 1, inputs * outputs, dtype=np.float32).reshape(inputs, outputs), "w")
    graph = helper.make_graph(
        [helper.make_node("MatMul", ["obs", "w"], ["q"])],
        "policy",
        [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["n", inputs])],
        [helper.make_tensor_value_info("q", TensorProto.FLOAT, ["n", outputs])],
        [w],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8  # readable by every onnxruntime the [onnx] extra allows
    onnx.checker.check_model(model)
    onnx.save_model(model, str(path))
    return path


def test_onnx_policy_with_five_outputs_is_told_about_its_output(tmp_path, capsys):
    five = _onnx_matmul(tmp_path / "five.onnx", D, 5)
    for command in (
        ["decision-map", "--resolution", "3", "--out", str(tmp_path / "m.png")],
        [
            "eval",
            "--suite",
            str(small_suite_file(tmp_path, count=2)),
            "--out",
            str(tmp_path / "r.json"),
            "--no-progress",
        ],
    ):
        err = one_line_error(capsys, command + ["--policy", str(five)])
        assert "does not accept observations" not in err, err
        assert "output" in err and "returned shape (2, 5)" in err and "3 mode scores" in err, err
    # A model for other observations is still told so; three scores still act.
    err = one_line_error(
        capsys,
        [
            "decision-map",
            "--resolution",
            "3",
            "--out",
            str(tmp_path / "m.png"),
            "--policy",
            str(_onnx_matmul(tmp_path / "wide.onnx", D + 1, 3)),
        ],
    )
    assert f"does not accept observations of shape (N, {D})" in err, err
    assert (
        main(
            [
                "decision-map",
                "--resolution",
                "3",
                "--out",
                str(tmp_path / "m.png"),
                "--policy",
                str(_onnx_matmul(tmp_path / "three.onnx", D, 3)),
            ]
        )
        == 0
    )


def test_modes_of_names_the_expected_output_shapes():
    from overtakezoo.benchmark.run.sandbox import BadAnswer, PolicyFailure, modes_of

    np.testing.assert_array_equal(modes_of(np.eye(3, dtype=np.float32)[[2, 0]], 2), [2, 0])
    np.testing.assert_array_equal(modes_of(np.array([[1], [2]]), 2), [1, 2])
    with pytest.raises(BadAnswer, match=r"returned shape \(4, 5\) for 4 observation\(s\), expected 3 mode scores"):
        modes_of(np.zeros((4, 5), np.float32), 4)
    with pytest.raises(BadAnswer, match="of dtype int64, expected floats"):
        modes_of(np.zeros((4, 3), np.int64), 4)
    assert issubclass(BadAnswer, PolicyFailure)


# ------------------------------------------------------------------ gymnasium.make of a multi-AV id
@pytest.mark.parametrize("make", ["make", "make_vec", "make_vec_sync"])
def test_gymnasium_make_of_a_multi_av_suite_points_at_pettingzoo(make):
    import gymnasium

    import overtakezoo.envs  # noqa: F401 (registers the ids)

    call = {
        "make": lambda i: gymnasium.make(i),
        "make_vec": lambda i: gymnasium.make_vec(i, num_envs=2),
        "make_vec_sync": lambda i: gymnasium.make_vec(i, num_envs=2, vectorization_mode="sync"),
    }[make]
    with pytest.raises(gymnasium.error.NameNotFound) as exc:  # what it was before: code catching it still does
        call("overtakezoo/duel-v1")
    text = str(exc.value)
    assert "multi-AV suite" in text and 'pettingzoo.make("parallel", "overtakezoo/duel-v1")' in text, text
    assert 'overtakezoo.envs.parallel_env("duel")' in text
    from overtakezoo.envs.faces.pettingzoo import MultiAVSuiteError

    assert isinstance(exc.value, MultiAVSuiteError)
    # ... and the calls it shows work.
    import pettingzoo

    assert pettingzoo.make("parallel", "overtakezoo/duel-v1").possible_agents == ["av_0", "av_1"]


# ------------------------------------------------------------------ dataset download without minari
def test_dataset_download_without_minari_says_so_before_any_rebuild(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("OVERTAKEZOO_HOME", str(tmp_path / "home"))
    monkeypatch.delenv("MINARI_DATASETS_PATH", raising=False)
    from overtakezoo import zoo
    from overtakezoo.envs.suites import load_suite

    name = "overtakezoo/table1/follow-v0"
    suite = load_suite("table1-train")  # a recipe this installation could rebuild (were minari there)
    recipe = {
        "suite": suite.name,
        "suite_sha256": suite.hash,
        "suite_version": suite.version,
        "count": 2,
        "chunk_size": 4096,
        "policies": [
            {
                "decider": "always-follow",
                "epsilon": 0.0,
                "seed": 0,
                "decider_version": str(zoo.load("always-follow", suite.config).version),
                "weights_sha256": None,
            }
        ],
    }
    registry = tmp_path / "registry.json"
    registry.write_text(json.dumps({"datasets": {name: {"mirrors": [], "recipe": recipe, "content_sha256": "0" * 64}}}))
    monkeypatch.setenv("OVERTAKEZOO_REGISTRY", str(registry))
    monkeypatch.setitem(sys.modules, "minari", None)  # a base install: `import minari` fails
    assert main(["dataset", "download", name, "--no-progress"]) == 2
    out, err = capsys.readouterr()
    assert "rebuild" not in out and "mirror" not in out, out  # nothing announced before the error
    assert err.startswith("error: ") and err.count("\n") == 1 and "minari" in err and "overtakezoo[data]" in err, err
    assert not (tmp_path / "home" / "datasets").exists()
