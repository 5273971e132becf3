"""Files are bounded before they are read (issue 35): each hostile file is built here, small on disk,
and must give one ``error:`` line instead of being read whole, inflated, stored or parsed into a traceback.

- ONNX external data through a symlinked folder, and initializers no node uses;
- memory bombs: an MCAP chunk, a Stable-Baselines3 ``policy.pth``, a dataset mirror's body;
- a built-in zoo member's weights submitted under a new name;
- control characters in an ``error:`` line;
- deeply nested JSON in every reader of outside files.
"""

from __future__ import annotations

import http.server
import io
import json
import os
import shutil
import struct
import threading
import zipfile
from pathlib import Path

import numpy as np
import pytest
from test_submissions import one_line_error

from overtakezoo.benchmark.cli import main
from overtakezoo.benchmark.errors import UserError
from overtakezoo.envs import EnvConfig, observation_size

D = observation_size(EnvConfig())
DEEP = b"[" * 100_000 + b"]" * 100_000  # 200 KB on disk; json.loads: RecursionError


def evaluate(capsys, suite, policy, out):
    code = main(["eval", "--suite", suite, "--policy", str(policy), "--out", str(out), "--no-progress"])
    return code, capsys.readouterr().err.strip()


# ----------------------------------------------------------------------------- 1. ONNX external data
def _onnx_model(extra: bool):
    """A Gemm policy (obs (N, D) -> q (N, 3)); ``extra``: plus an initializer no node reads."""
    onnx = pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    from onnx import TensorProto, helper, numpy_helper

    rng = np.random.default_rng(0)
    inits = [
        numpy_helper.from_array(rng.normal(size=(3, D)).astype(np.float32), "W"),
        numpy_helper.from_array(np.zeros(3, np.float32), "B"),
    ]
    if extra:
        inits.append(numpy_helper.from_array(np.zeros(4, np.uint8), "extra"))
    graph = helper.make_graph(
        [helper.make_node("Gemm", ["obs", "W", "B"], ["q"], transB=1)],
        "policy",
        [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["n", D])],
        [helper.make_tensor_value_info("q", TensorProto.FLOAT, ["n", 3])],
        inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    return onnx, model


def _external(onnx, tensor, location: str, length: int | None = None) -> bytes:
    """Point ``tensor`` at ``location`` (external data); returns the bytes it held."""
    raw = tensor.raw_data or onnx.numpy_helper.to_array(tensor).tobytes()
    tensor.ClearField("raw_data")
    tensor.data_location = onnx.TensorProto.EXTERNAL
    entries = [("location", location), ("offset", "0")] + ([("length", str(length))] if length else [])
    for key, value in entries:
        e = tensor.external_data.add()
        e.key, e.value = key, value
    return raw


def test_onnx_unused_initializer_through_a_symlinked_proc_folder_is_refused(tmp_path, tiny, capsys):
    """The issue's attack: `d -> /proc/self`, an initializer no node uses stored at d/environ."""
    onnx, model = _onnx_model(extra=True)
    folder = tmp_path / "m"
    folder.mkdir()
    os.symlink("/proc/self", folder / "d")
    extra = next(t for t in model.graph.initializer if t.name == "extra")
    _external(onnx, extra, "d/environ")
    (folder / "m.onnx").write_bytes(model.SerializeToString())
    code, err = evaluate(capsys, tiny, folder / "m.onnx", tmp_path / "r.json")
    assert code == 2 and err.startswith("error: ") and "\n" not in err, err  # before: 0, environ inlined
    assert "'extra' is used by no node" in err
    assert not (tmp_path / "r.json").exists()


def test_onnx_external_data_through_a_symlinked_folder_is_refused(tmp_path, tiny, capsys):
    """Used weights, but their folder is a symlink (here to a folder beside it): never followed."""
    onnx, model = _onnx_model(extra=False)
    folder, real = tmp_path / "m", tmp_path / "elsewhere"
    folder.mkdir()
    real.mkdir()
    os.symlink(real, folder / "d")
    w = next(t for t in model.graph.initializer if t.name == "W")
    (real / "w.bin").write_bytes(_external(onnx, w, "d/w.bin"))
    (folder / "m.onnx").write_bytes(model.SerializeToString())
    code, err = evaluate(capsys, tiny, folder / "m.onnx", tmp_path / "r.json")
    assert code == 2 and "without a symlink" in err and "\n" not in err, err  # before: 0 (followed)
    # The same data in a real subfolder is read (and the length is honoured).
    os.unlink(folder / "d")
    (folder / "d").mkdir()
    shutil.copy(real / "w.bin", folder / "d" / "w.bin")
    assert evaluate(capsys, tiny, folder / "m.onnx", tmp_path / "r.json")[0] == 0


def test_onnx_external_data_past_its_file_is_refused(tmp_path):
    from overtakezoo.benchmark.run.artifacts import read_policy_file

    onnx, model = _onnx_model(extra=False)
    w = next(t for t in model.graph.initializer if t.name == "W")
    raw = _external(onnx, w, "w.bin", length=1 << 40)  # a length far past the file's end
    (tmp_path / "w.bin").write_bytes(raw)
    (tmp_path / "m.onnx").write_bytes(model.SerializeToString())
    with pytest.raises(UserError, match="not inside the file"):
        read_policy_file(tmp_path / "m.onnx", (tmp_path / "m.onnx").read_bytes(), None)


# ----------------------------------------------------------------------------- 2a. MCAP chunk bomb
def _mcap_bomb(path: Path, inflated: int, declared: int) -> Path:
    """An OvertakeZoo archive (one episode) whose one chunk holds ``inflated`` zero bytes, zstd-packed
    (a few KB), and declares ``declared`` bytes uncompressed (CRC 0: not checked)."""
    import zstandard
    from mcap.opcode import Opcode
    from mcap.records import ChunkIndex

    from overtakezoo.benchmark.archive.format import FORMAT_VERSION, STATE_TOPICS
    from overtakezoo.benchmark.archive.mcapfile import McapFile, _string

    packed = zstandard.ZstdCompressor().compress(b"\0" * inflated)  # (its frame header says how much)
    with open(path, "wb") as f:
        m = McapFile(f)
        cids = [m.register(t, t, "jsonschema", b"{}", "json") for t in STATE_TOPICS]
        head = struct.pack("<QQQI", 0, 10, declared, 0) + _string("zstd") + struct.pack("<Q", len(packed))
        start = m._pos
        m._write(struct.pack("<BQ", Opcode.CHUNK, len(head) + len(packed)) + head + packed)
        m._chunk_indexes.append(
            ChunkIndex(
                message_start_time=0,
                message_end_time=10,
                chunk_start_offset=start,
                chunk_length=m._pos - start,
                message_index_offsets={c: start for c in cids},
                message_index_length=0,
                compression="zstd",
                compressed_size=len(packed),
                uncompressed_size=declared,
            )
        )
        m.add_metadata("overtakezoo", {"format_version": FORMAT_VERSION})
        m.add_metadata(
            "episode",
            {
                "episode": "0",
                "start_ns": "0",
                "end_ns": "10",
                "steps": "1",
                "outcome": "success",
                "episode_return": "0",
            },
        )
        m.finish()
    assert path.stat().st_size < 64 << 10
    return path


@pytest.mark.parametrize(
    "inflated, declared, says",
    [
        (1 << 20, 8 << 30, "declares 8589934592 bytes uncompressed"),  # refused before anything is inflated
        (4 << 20, 1000, "inflates past its declared 1000 bytes"),  # stopped one byte past what it declares
    ],
)
def test_an_mcap_chunk_bomb_is_refused(tmp_path, capsys, inflated, declared, says):
    bomb = _mcap_bomb(tmp_path / "bomb.mcap", inflated, declared)
    assert main(["replay", str(bomb), "--list"]) == 0  # the index is the summary's: no chunk is read
    capsys.readouterr()
    err = one_line_error(capsys, ["replay", str(bomb), "--episode", "0", "--out", str(tmp_path / "e.png")])
    assert says in err and "bomb.mcap" in err, err  # before: inflated whole (8 GiB), then "incomplete"
    assert not (tmp_path / "e.png").exists()


def test_mcap_chunk_inflation_is_bounded_in_memory(tmp_path):
    """The bounded reader never holds more than the declared size + 1 byte of a lying chunk."""
    import zstandard
    from mcap.records import Chunk

    from overtakezoo.benchmark.archive.reader import _inflate

    data = zstandard.ZstdCompressor().compress(b"\0" * (32 << 20))
    with pytest.raises(UserError, match="inflates past"):
        _inflate(
            tmp_path / "x.mcap",
            0,
            Chunk(
                compression="zstd",
                data=data,
                message_start_time=0,
                message_end_time=0,
                uncompressed_crc=0,
                uncompressed_size=10,
            ),
        )


# ----------------------------------------------------------------------------- 2b. SB3 zip bomb
def _sb3_bomb(path: Path, inflated: int) -> Path:
    """A Stable-Baselines3-looking .zip whose policy.pth is ``inflated`` zero bytes, deflated (~1000:1)."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("data", json.dumps({"policy_class": {"__module__": "stable_baselines3.dqn.policies"}}))
        with z.open("policy.pth", "w", force_zip64=True) as f:
            for _ in range(inflated >> 20):
                f.write(b"\0" * (1 << 20))
    return path


def test_an_sb3_zip_whose_policy_pth_inflates_past_the_cap_is_refused(tmp_path, tiny, capsys):
    pytest.importorskip("torch")
    from overtakezoo.benchmark.run.artifacts import MAX_SB3_STATE_BYTES

    bomb = _sb3_bomb(tmp_path / "bomb.zip", MAX_SB3_STATE_BYTES + (1 << 20))
    assert bomb.stat().st_size < 1 << 20  # 65 MiB of zeros in ~65 KB
    code, err = evaluate(capsys, tiny, bomb, tmp_path / "r.json")
    assert code == 2 and "\n" not in err, err
    assert f"policy.pth declares {MAX_SB3_STATE_BYTES + (1 << 20)} bytes uncompressed" in err, err
    assert "weights_only" not in err


def test_a_torch_file_with_a_compressed_record_is_refused_and_torch_advice_is_not_repeated(tmp_path, tiny, capsys):
    torch = pytest.importorskip("torch")
    buf = io.BytesIO()
    torch.save({"q_net.q_net.0.weight": torch.zeros(2, 2)}, buf)
    # The same records deflated: torch's reader would inflate them whole (a bomb inside the bomb check).
    packed = io.BytesIO()
    with zipfile.ZipFile(buf) as src, zipfile.ZipFile(packed, "w", zipfile.ZIP_DEFLATED) as dst:
        for info in src.infolist():
            dst.writestr(info.filename, src.read(info))
    for name, pth in (("packed", packed.getvalue()), ("pickle", _pickle_pth(torch))):
        path = tmp_path / f"{name}.zip"
        with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
            z.writestr("data", json.dumps({"policy_class": {"__module__": "stable_baselines3.dqn.policies"}}))
            z.writestr("policy.pth", pth)
        code, err = evaluate(capsys, tiny, path, tmp_path / "r.json")
        assert code == 2 and "\n" not in err, err
        assert "weights_only" not in err and "still be loaded" not in err, err
        assert ("is compressed" in err) if name == "packed" else ("not a plain state dict" in err), err


def _pickle_pth(torch) -> bytes:
    buf = io.BytesIO()
    torch.save({"q_net.q_net.0.weight": Path("/nonexistent")}, buf)  # a global weights_only refuses
    return buf.getvalue()


# ----------------------------------------------------------------------------- 2c. dataset mirror overflow
class Overflowing(http.server.BaseHTTPRequestHandler):
    """Streams ``total`` bytes whatever the registry says; ``announce``: with a Content-Length."""

    total = 32 << 20
    announce = False
    sent = 0
    done = threading.Event()

    def do_GET(self):  # noqa: N802 - http.server's naming
        cls = type(self)
        self.send_response(200)
        if cls.announce:
            self.send_header("Content-Length", str(cls.total))
        self.end_headers()
        block = b"x" * (64 << 10)
        try:
            while cls.sent < cls.total:
                self.wfile.write(block)
                cls.sent += len(block)
        except OSError:
            pass
        finally:
            cls.done.set()

    def log_message(self, *args):
        pass


@pytest.mark.parametrize("announce", [False, True])
def test_a_mirror_sending_more_than_the_registry_size_is_cut_off(tmp_path, monkeypatch, capsys, announce):
    pytest.importorskip("minari")
    monkeypatch.setenv("OVERTAKEZOO_HOME", str(tmp_path / "home"))
    monkeypatch.delenv("MINARI_DATASETS_PATH", raising=False)
    monkeypatch.setenv("OVERTAKEZOO_REGISTRY", str(tmp_path / "registry.json"))
    Overflowing.sent, Overflowing.announce, Overflowing.done = 0, announce, threading.Event()
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Overflowing)
    thread = threading.Thread(target=httpd.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    try:
        name = "overtakezoo/big/x-v0"
        url = f"http://127.0.0.1:{httpd.server_address[1]}/x.tar.gz"
        (tmp_path / "registry.json").write_text(
            json.dumps({"datasets": {name: {"url": url, "size": 1000, "sha256": "0" * 64}}})
        )
        err = one_line_error(capsys, ["dataset", "download", name, "--no-progress", "--no-build"])
        assert Overflowing.done.wait(10)
    finally:
        httpd.shutdown()
        httpd.server_close()
    says = "announced 33554432 bytes" if announce else "sent more than the registry's 1000 bytes"
    assert says in err and "deleted the partial file" in err, err  # before: 32 MiB read, then "checksum mismatch"
    assert Overflowing.sent < Overflowing.total  # the client hung up: the rest was never sent
    assert not list((tmp_path / "home").rglob("*.part"))


# ----------------------------------------------------------------------------- 3. zoo weights renamed
def test_a_zoo_members_weights_under_a_new_name_are_refused(tmp_path, tiny, capsys):
    from overtakezoo.zoo.members.learned import PRETRAINED

    for ext in (".npz", ".json"):
        shutil.copy(PRETRAINED / f"dqn{ext}", tmp_path / f"mine{ext}")
    assert evaluate(capsys, tiny, tmp_path / "mine.npz", tmp_path / "r.json")[0] == 0
    err = one_line_error(
        capsys,
        [
            "submit",
            str(tmp_path / "r.json"),
            "--name",
            "mine",
            "--policy",
            str(tmp_path / "mine.npz"),
            "--root",
            str(tmp_path / "lb"),
        ],
    )
    assert "built-in zoo member 'dqn'" in err, err  # before: filed as the row "mine"
    assert not list((tmp_path / "lb").rglob("mine.json"))


def test_zoo_weights_are_recognised_in_onnx_and_float32(tmp_path):
    """The same matrices in another format and precision (an ONNX export, transposed for MatMul)."""
    pytest.importorskip("onnx")
    from onnx import TensorProto, helper, numpy_helper

    from overtakezoo.benchmark.leaderboard.submission import zoo_weights_of
    from overtakezoo.benchmark.run.artifacts import Artifact
    from overtakezoo.zoo.members.learned import PRETRAINED

    with np.load(PRETRAINED / "ppo.npz") as z:
        arrays = {k: z[k] for k in z.files}
    n = sum(k.endswith(".weight") for k in arrays)
    nodes, inits, x = [], [], "obs"
    for i in range(n):
        inits += [
            numpy_helper.from_array(arrays[f"layer{i}.weight"].T.astype(np.float32), f"w{i}"),
            numpy_helper.from_array(arrays[f"layer{i}.bias"].astype(np.float32), f"b{i}"),
        ]
        nodes += [
            helper.make_node("MatMul", [x, f"w{i}"], [f"m{i}"]),
            helper.make_node("Add", [f"m{i}", f"b{i}"], [f"h{i}"]),
        ]
        x = f"h{i}"
    graph = helper.make_graph(
        nodes,
        "g",
        [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["n", None])],
        [helper.make_tensor_value_info(x, TensorProto.FLOAT, ["n", None])],
        inits,
    )
    data = helper.make_model(graph).SerializeToString()
    assert zoo_weights_of(Artifact("onnx", data)) == "ppo"
    other = {k: v + 1e-3 for k, v in arrays.items()}  # other weights: not a member
    from overtakezoo.zoo.members.mlp import npz_bytes

    assert zoo_weights_of(Artifact("mlp", npz_bytes(other))) is None
    assert zoo_weights_of(Artifact("mlp", npz_bytes(arrays))) == "ppo"


# ----------------------------------------------------------------------------- 4. control characters
def test_error_lines_escape_control_characters(tmp_path, capsys):
    evil = tmp_path / "x\x1b[31mred\rover\nline\u202e.zip"
    assert main(["card", str(evil), "--action-repeat", "1"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1, repr(err)  # before: raw ESC, CR and LF
    assert "\x1b" not in err and "\r" not in err and "\u202e" not in err
    assert "x\\x1b[31mred\\rover\\nline\\u202e.zip" in err


# ----------------------------------------------------------------------------- 5. deep JSON
def test_deep_json_in_leaderboard_files_is_one_error(tmp_path):
    from overtakezoo.benchmark.leaderboard import crossplay, generate, headline

    root = tmp_path / "lb"
    (root / "reference").mkdir(parents=True)
    (root / "seeds").mkdir()
    (root / "crossplay").mkdir()
    for rel in (
        "reference/paper.json",
        "reference/table1-shape.json",
        "seeds/dqn.json",
        "crossplay/duel.json",
        "index.json",
    ):
        (root / rel).write_bytes(DEEP)
    checks = [
        (lambda: generate.load_reference(root), "paper.json"),
        (lambda: headline.load_seeds(root), "dqn.json"),
        (lambda: crossplay.load(root / "crossplay" / "duel.json"), "duel.json"),
    ]
    for call, name in checks:
        with pytest.raises(UserError) as exc:  # before: RecursionError
            call()
        assert name in str(exc.value) and "nested 100000 levels deep" in str(exc.value)
    assert generate.owned_files(root, {"a.md": b""}) == {"a.md"}  # a malformed previous index counts as none


def test_deep_json_in_cards_registry_results_and_rows_is_one_error(tmp_path, tiny, capsys, monkeypatch):
    from overtakezoo.benchmark.leaderboard.submission import _references
    from overtakezoo.zoo.members.learned import PRETRAINED

    # A model card beside its weights (`overtakezoo train` output).
    shutil.copy(PRETRAINED / "dqn.npz", tmp_path / "w.npz")
    (tmp_path / "w.json").write_bytes(DEEP)
    code, err = evaluate(capsys, tiny, tmp_path / "w.npz", tmp_path / "r.json")
    assert code == 2 and "w.json" in err and "nested" in err and "\n" not in err, err
    code, err = evaluate(capsys, tiny, tmp_path / "w.json", tmp_path / "r.json")  # the card given as the policy
    assert code == 2 and "\n" not in err, err
    # A policy card beside an SB3 .zip, and an SB3 .zip's own "data".
    with zipfile.ZipFile(tmp_path / "m.zip", "w") as z:
        z.writestr("data", DEEP)
        z.writestr("policy.pth", b"")
    code, err = evaluate(capsys, tiny, tmp_path / "m.zip", tmp_path / "r.json")
    assert code == 2 and "nested" in err and "\n" not in err, err
    (tmp_path / "m.card.json").write_bytes(b"[" * 30_000 + b"]" * 30_000)
    code, err = evaluate(capsys, tiny, tmp_path / "m.zip", tmp_path / "r.json")
    assert code == 2 and "m.card.json" in err and "nested" in err and "\n" not in err, err
    # The dataset registry.
    monkeypatch.setenv("OVERTAKEZOO_REGISTRY", str(tmp_path / "registry.json"))
    (tmp_path / "registry.json").write_bytes(DEEP)
    err = one_line_error(capsys, ["dataset", "list"])
    assert "registry.json" in err and "nested" in err
    # A results file, and a row read for its references.
    (tmp_path / "deep.json").write_bytes(DEEP)
    err = one_line_error(capsys, ["submit", str(tmp_path / "deep.json"), "--root", str(tmp_path / "lb")])
    assert "deep.json" in err and "nested" in err
    (tmp_path / "lb" / "submissions" / "tiny").mkdir(parents=True)
    (tmp_path / "lb" / "submissions" / "tiny" / "row.json").write_bytes(DEEP)
    assert _references(tmp_path / "lb") is None  # unreadable: nothing is pruned


def test_the_depth_scan_skips_strings_and_allows_ordinary_files():
    from overtakezoo.envs.safe_json import MAX_JSON_DEPTH, JSONInputError, depth, loads

    assert (
        depth(b'{"a": "' + b"[" * 100 + b'\\"' + b"{" * 100 + b'", "b": [[1], {"c": []}]}') == 4
    )  # object, array, object, array
    assert loads(b'["' + b"[" * 10_000 + b'"]', "x") == ["[" * 10_000]
    ok = b"[" * MAX_JSON_DEPTH + b"]" * MAX_JSON_DEPTH
    assert loads(ok, "x") is not None
    with pytest.raises(JSONInputError, match="nested 65 levels deep"):
        loads(b"[" + ok + b"]", "x")
    with pytest.raises(JSONInputError, match="more than 10 bytes"):
        loads(b"[1, 2, 3, 4, 5]", "x", max_bytes=10)


def test_an_npz_weights_bomb_is_refused_before_inflating():
    import io
    import zipfile

    from overtakezoo.zoo.members.mlp import MAX_NPZ_BYTES, read_npz

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:  # ~70 KB on disk, 65 MiB inflated
        zf.writestr("layer0.weight.npy", b"\0" * (MAX_NPZ_BYTES + (1 << 20)))
    assert len(buf.getvalue()) < 1 << 20
    with pytest.raises(ValueError, match="inflates to"):
        read_npz(buf.getvalue())


# ----------------------------------------------------------------------------- 2d. a memory cap around every parse
def test_a_parse_past_its_memory_budget_is_one_error_and_the_limit_is_restored():
    import resource

    from overtakezoo.benchmark.memory_cap import memory_cap

    before = resource.getrlimit(resource.RLIMIT_AS)
    with pytest.raises(UserError, match=r"^thing\.bin: reading it needs more than 64 MiB of memory"):
        with memory_cap("thing.bin", budget=64 << 20):
            np.ones(512 << 20, np.uint8)  # a parser inflating half a GiB
    assert resource.getrlimit(resource.RLIMIT_AS) == before
    assert np.ones(512 << 20, np.uint8).sum() == 512 << 20  # the process is whole again
    with memory_cap("small.bin", budget=64 << 20):
        assert np.ones(8 << 20, np.uint8).size == 8 << 20  # within the budget: untouched


def test_an_archive_whose_honest_chunk_exceeds_the_parse_budget_is_one_error(tmp_path):
    """Past the size checks (a chunk that declares what it inflates to, under the chunk cap) the memory
    cap still holds: with a 16 MiB budget, a 48 MiB chunk ends `replay` with one line. (In a process of
    its own: in a test worker whose earlier tests left threads behind, where the budget runs out first
    varies, and a parser may then report a short read instead of the allocation that failed.)"""
    import subprocess
    import sys

    archive = _mcap_bomb(tmp_path / "big.mcap", 48 << 20, 48 << 20)
    code = (
        "import sys; from overtakezoo.benchmark import memory_cap; memory_cap.PARSE_BUDGET = 16 << 20; "
        "from overtakezoo.benchmark.cli import main; sys.exit(main(sys.argv[1:]))"
    )
    argv = ["replay", str(archive), "--episode", "0", "--out", str(tmp_path / "e.png")]
    done = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True, timeout=120)
    err = done.stderr.strip()
    assert done.returncode == 2 and err.count("\n") == 0, err
    assert "big.mcap: reading it needs more than 16 MiB of memory" in err, err
    assert not (tmp_path / "e.png").exists()
