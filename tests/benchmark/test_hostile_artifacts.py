"""Hostile policy files: crafted here, fed to `eval --policy`, `submit`, `leaderboard --verify` and
`train --resume`. None may run code, write a file, hang, or put a number on the board that the
verifier did not reproduce from what the row stores."""

from __future__ import annotations

import base64
import hashlib
import io
import json
import pickle
import time
import warnings
import zipfile
from pathlib import Path

import pytest
from test_submissions import one_line_error, scripted_policy

from overtakezoo.benchmark.cli import main
from overtakezoo.benchmark.results.results import Results
from overtakezoo.benchmark.run.sandbox import landlock_abi
from overtakezoo.envs import EnvConfig, observation_size, suites
from overtakezoo.envs.io import file_sha256

torch = pytest.importorskip("torch")
pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")
D = observation_size(EnvConfig())


class Plant:
    """Unpickling this creates ``path`` (what a payload would do with any code)."""

    def __init__(self, path: Path) -> None:
        self.path = str(path)

    def __reduce__(self):
        return (open, (self.path, "w"))


def evaluate(capsys, suite, spec, out):
    code = main(["eval", "--suite", suite, "--policy", str(spec), "--out", str(out), "--no-progress"])
    captured = capsys.readouterr()
    return code, captured.err.strip()


# ----------------------------------------------------------------------------- Stable-Baselines3
def _sb3_zip(tmp_path: Path, marker: Path) -> Path:
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import DQN

    from overtakezoo.envs import OvertakeEnv  # the env's defaults: only its spaces matter (tiny replaces the suites)

    model = DQN("MlpPolicy", OvertakeEnv(), seed=0, verbose=0, device="cpu", policy_kwargs={"net_arch": [16]})
    model.save(tmp_path / "honest.zip")
    payload = base64.b64encode(pickle.dumps(Plant(marker))).decode()
    out = tmp_path / "hostile.zip"
    with zipfile.ZipFile(tmp_path / "honest.zip") as src, zipfile.ZipFile(out, "w") as dst:
        for item in src.namelist():
            data = src.read(item)
            if item == "data":  # every cloudpickled entry replaced by the payload; SB3's load unpickles them
                doc = json.loads(data)
                for value in doc.values():
                    if isinstance(value, dict) and ":serialized:" in value:
                        value[":serialized:"] = payload
                data = json.dumps(doc).encode()
            dst.writestr(item, data)
    return out


def test_sb3_zip_is_read_as_data_and_its_pickles_never_run(tmp_path, tiny, capsys):
    marker = tmp_path / "pwned-sb3"
    hostile = _sb3_zip(tmp_path, marker)
    code, err = evaluate(capsys, tiny, hostile, tmp_path / "r.json")
    assert code == 0, err
    assert not marker.exists()
    doc = json.loads((tmp_path / "r.json").read_text())
    assert doc["decider"]["policy"]["kind"] == "sb3" and doc["decider"]["weights_sha256"] == file_sha256(hostile)
    # Submitted, it is stored as the npz MLP (data), and the row verifies from that alone.
    root = tmp_path / "lb"
    assert (
        main(["submit", str(tmp_path / "r.json"), "--name", "sb3-row", "--policy", str(hostile), "--root", str(root)])
        == 0
    )
    stored = sorted(p.suffix for p in (root / "submissions" / "artifacts").iterdir())
    assert stored == [".json", ".npz"]
    assert main(["leaderboard", "--root", str(root), "--verify"]) == 0
    assert not marker.exists()


def test_a_policy_state_dict_holding_a_pickle_is_refused(tmp_path, tiny, capsys):
    marker = tmp_path / "pwned-pth"
    honest = _sb3_zip(tmp_path, tmp_path / "unused")
    evil = tmp_path / "evil.zip"
    with zipfile.ZipFile(honest) as src, zipfile.ZipFile(evil, "w") as dst:
        for item in src.namelist():
            data = src.read(item)
            if item == "policy.pth":
                buf = io.BytesIO()
                torch.save({"q_net.q_net.0.weight": Plant(marker)}, buf)
                data = buf.getvalue()
            dst.writestr(item, data)
    code, err = evaluate(capsys, tiny, evil, tmp_path / "r.json")
    assert code == 2 and "not a plain state dict" in err and "\n" not in err
    assert not marker.exists()


# ----------------------------------------------------------------------------- TorchScript
WRITER = '''
import torch

class Writer(torch.nn.Module):
    """Writes 8 bytes into `path` whenever it acts (torch.from_file with shared memory)."""
    def __init__(self, path: str):
        super().__init__()
        self.path = path

    def forward(self, x):
        t = torch.from_file(self.path, shared=True, size=8, dtype=torch.uint8)
        t.copy_(torch.full([8], 65, dtype=torch.uint8))
        return x[:, :3] + t[:3].to(torch.float32) * 0.0  # (used: the JIT keeps the write)

class Reader(torch.nn.Module):
    """Reads 8 bytes of `path` whenever it acts (what a policy would smuggle out in its decisions,
    or in the ONNX file `submit` converts it to)."""
    def __init__(self, path: str):
        super().__init__()
        self.path = path

    def forward(self, x):
        t = torch.from_file(self.path, shared=False, size=8, dtype=torch.uint8)
        return x[:, :3] + t[:3].to(torch.float32) * 0.0

class Slow(torch.nn.Module):
    """Fast on the load probe's zeros, then a loop of minutes (TorchScript ignores SIGTERM)."""
    def forward(self, x):
        y = x[:, :3] * 0.0
        if bool(x.abs().sum() > 0.0):
            for i in range(2000000000):
                y = y + 1.0
        return y

class Bad(torch.nn.Module):
    """Fine on zeros; on real observations: mode 7, NaN scores or a fourth score column."""
    def __init__(self, how: int):
        super().__init__()
        self.how = how

    def forward(self, x):
        real = bool(x.abs().sum() > 0.0)
        if real and self.how == 0:
            return torch.full([x.shape[0]], 7, dtype=torch.int64).to(torch.float32)
        if real and self.how == 1:
            return x[:, :3] * float("nan")
        if real and self.how == 2:
            return x[:, :4]
        return x[:, :3] * 0.0
'''


@pytest.fixture
def scripts(tmp_path, monkeypatch):
    (tmp_path / "hostile_modules.py").write_text(WRITER)
    monkeypatch.syspath_prepend(str(tmp_path))
    import importlib

    return importlib.import_module("hostile_modules")


def test_torchscript_that_writes_files_writes_nothing(tmp_path, tiny, capsys, scripts, monkeypatch):
    if landlock_abi() < 1:
        pytest.skip("this kernel has no Landlock (Linux >= 5.13): the box only limits file sizes (next test)")
    outside = tmp_path / "checkout"
    outside.mkdir()
    (outside / "existing.py").write_text("# a file of the checkout\n")
    # A new file by absolute path, an existing one overwritten in place, one in the working directory.
    for target in (outside / "conftest.py", outside / "existing.py", Path("conftest.py")):
        torch.jit.save(torch.jit.script(scripts.Writer(str(target))), tmp_path / "writer.pt")
        # It works when nothing holds it back (the payload is real) ...
        probe = torch.jit.load(str(tmp_path / "writer.pt"))
        scratch = tmp_path / "scratch"
        scratch.mkdir(exist_ok=True)
        monkeypatch.chdir(scratch)
        if not target.is_absolute():
            probe(torch.ones(1, D))
            assert (scratch / "conftest.py").read_bytes() == b"A" * 8
        monkeypatch.chdir(outside)
        code, err = evaluate(capsys, tiny, tmp_path / "writer.pt", tmp_path / "r.json")
        if target.is_absolute():  # refused by the kernel; a relative path lands in the box's own temp directory
            assert code == 2 and err.startswith("error: ") and "\n" not in err, err
        assert not (outside / "conftest.py").exists()
        assert (outside / "existing.py").read_text() == "# a file of the checkout\n"


def test_torchscript_reads_no_file_outside_the_code_it_imports(
    tmp_path_factory, tmp_path, tiny, capsys, scripts, monkeypatch
):
    """A secret in the user's home (here a folder of its own, on no sys.path) or in /etc: the box
    refuses the read; the same module reads it unboxed (the payload is real)."""
    if landlock_abi() < 1:
        pytest.skip("this kernel has no Landlock (Linux >= 5.13)")
    secret = tmp_path_factory.mktemp("home") / ".token"
    secret.write_bytes(b"API-TOKEN-0123456789")
    for target in (secret, Path("/etc/passwd")):
        if not target.is_file():
            continue
        torch.jit.save(torch.jit.script(scripts.Reader(str(target))), tmp_path / "reader.pt")
        assert torch.jit.load(str(tmp_path / "reader.pt"))(torch.ones(1, D)).shape == (1, 3)  # reads, unboxed
        code, err = evaluate(capsys, tiny, tmp_path / "reader.pt", tmp_path / "r.json")
        assert code == 2 and err.startswith("error: ") and "\n" not in err, err
        assert "Permission denied" in err, err
        assert not (tmp_path / "r.json").exists()
    monkeypatch.setenv("OVERTAKEZOO_SANDBOX_LANDLOCK", "0")  # the box without Landlock: the read goes through
    assert evaluate(capsys, tiny, tmp_path / "reader.pt", tmp_path / "r.json")[0] == 0


def test_without_landlock_no_file_grows(tmp_path, tiny, capsys, scripts, monkeypatch):
    """The fallback where the kernel has no Landlock: a 0-byte file-size limit; a new file stays empty."""
    monkeypatch.setenv("OVERTAKEZOO_SANDBOX_LANDLOCK", "0")
    target = tmp_path / "outside" / "conftest.py"
    target.parent.mkdir()
    torch.jit.save(torch.jit.script(scripts.Writer(str(target))), tmp_path / "writer.pt")
    code, err = evaluate(capsys, tiny, tmp_path / "writer.pt", tmp_path / "r.json")
    assert code == 2 and "\n" not in err
    assert not target.exists() or target.read_bytes() == b""


def test_a_hanging_policy_is_killed_and_named(tmp_path, tiny, capsys, scripts, monkeypatch):
    monkeypatch.setenv("OVERTAKEZOO_SANDBOX_CALL_S", "3")
    torch.jit.save(torch.jit.script(scripts.Slow()), tmp_path / "slow.pt")
    t0 = time.monotonic()
    code, err = evaluate(capsys, tiny, tmp_path / "slow.pt", tmp_path / "r.json")
    assert time.monotonic() - t0 < 60
    assert code == 2 and "did not answer within 3 s (killed)" in err and "\n" not in err
    assert "scenarios 0-11, step 0" in err and not (tmp_path / "r.json").exists()


@pytest.mark.parametrize(
    "how, says", [(0, "returned mode 7.0"), (1, "returned non-finite scores"), (2, "returned shape (12, 4)")]
)
def test_a_misbehaving_policy_is_one_line_naming_scenario_and_step(tmp_path, tiny, capsys, scripts, how, says):
    torch.jit.save(torch.jit.script(scripts.Bad(how)), tmp_path / "bad.pt")
    code, err = evaluate(capsys, tiny, tmp_path / "bad.pt", tmp_path / "r.json")
    assert code == 2 and says in err and "\n" not in err, err
    assert "step 0 (t = 0.0 s)" in err and ("scenario 0" in err or "scenarios 0-11" in err)


# ----------------------------------------------------------------------------- ONNX external data
def _onnx_with_external_data(directory: Path, seed: int) -> Path:
    pytest.importorskip("onnxruntime")
    onnx = pytest.importorskip("onnx")
    torch.manual_seed(seed)
    net = torch.nn.Sequential(torch.nn.Linear(D, 16), torch.nn.ReLU(), torch.nn.Linear(16, 3)).eval()
    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            net,
            (torch.zeros(1, D),),
            buf,
            input_names=["obs"],
            output_names=["q"],
            dynamic_axes={"obs": {0: "n"}, "q": {0: "n"}},
            dynamo=False,
        )
    directory.mkdir(parents=True, exist_ok=True)
    model = onnx.load_model_from_string(buf.getvalue())
    onnx.save_model(
        model,
        str(directory / "m.onnx"),
        save_as_external_data=True,
        all_tensors_to_one_file=True,
        location="m.onnx.data",
        size_threshold=0,
    )
    return directory / "m.onnx"


def test_onnx_external_data_is_inlined_and_hashed(tmp_path, tiny, capsys, monkeypatch):
    a = _onnx_with_external_data(tmp_path / "a", 0)
    b = _onnx_with_external_data(tmp_path / "b", 1)
    assert a.read_bytes() == b.read_bytes()  # the same .onnx bytes, other weights beside them
    monkeypatch.chdir(tmp_path)  # not the model's directory: the data is still found beside the model
    assert evaluate(capsys, tiny, a, tmp_path / "ra.json")[0] == 0
    assert evaluate(capsys, tiny, b, tmp_path / "rb.json")[0] == 0
    ra, rb = (json.loads((tmp_path / f).read_text()) for f in ("ra.json", "rb.json"))
    # The recorded sha256 covers the external data: different weights, different hashes.
    assert ra["decider"]["weights_sha256"] != rb["decider"]["weights_sha256"]
    assert ra["decider"]["weights_sha256"] != file_sha256(a)
    # Submitted: one self-contained file is stored, and the row verifies without the .data file.
    root = tmp_path / "lb"
    assert main(["submit", str(tmp_path / "ra.json"), "--name", "ext", "--policy", str(a), "--root", str(root)]) == 0
    (a.parent / "m.onnx.data").unlink()
    (stored,) = (root / "submissions" / "artifacts").iterdir()
    import onnx
    from onnx.external_data_helper import uses_external_data

    model = onnx.load_model_from_string(stored.read_bytes())
    assert not any(uses_external_data(t) for t in model.graph.initializer)
    assert main(["leaderboard", "--root", str(root), "--verify"]) == 0
    # Data outside the model's directory is refused, not read.
    onnx_model = onnx.load(str(b), load_external_data=False)
    for t in onnx_model.graph.initializer:
        for e in t.external_data:
            if e.key == "location":
                e.value = "../a/secret.data"
    onnx.save_model(onnx_model, str(tmp_path / "b" / "escape.onnx"))
    code, err = evaluate(capsys, tiny, tmp_path / "b" / "escape.onnx", tmp_path / "re.json")
    assert code == 2 and "is not a file beside the model" in err


# ----------------------------------------------------------------------------- stored formats only
def _direct_row(
    root: Path, suite: str, name: str, results: Results, artifact: bytes, ext: str, card: bytes | None = None
) -> Path:
    """A row as a hostile pull request writes it, its labels set as verify derives them."""
    sha = hashlib.sha256(artifact).hexdigest()
    store = root / "submissions" / "artifacts"
    store.mkdir(parents=True, exist_ok=True)
    (store / f"{sha}{ext}").write_bytes(artifact)
    policy = {"artifact": f"artifacts/{sha}{ext}", "sha256": sha}
    if card is not None:
        (store / f"{sha}.json").write_bytes(card)
        policy["card_sha256"] = hashlib.sha256(card).hexdigest()
    kind = "onnx" if ext == ".onnx" else "overtakezoo-dqn"
    decider = {
        "name": name,
        "version": "1",
        "weights_sha256": sha,
        "privileged": False,
        "policy": {"kind": kind, "file": f"{sha}{ext}", "sha256": sha},
    }
    path = root / "submissions" / suite / f"{name}.json"
    # a well-formed fresh draw (the public outcomes): verify gets to run the artifact itself
    outcome = results.per["outcome"][:500]
    fresh = {"seed": 7, "count": outcome.size, "outcomes": "".join(map(str, outcome.tolist()))}
    doc = {**results.to_dict(), "decider": decider, "submission": {"name": name, "policy": policy, "fresh": fresh}}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc))
    return path


def test_a_row_storing_code_is_refused_by_verify(tmp_path, tiny, capsys, scripts):
    torch.jit.save(torch.jit.script(scripts.Writer(str(tmp_path / "pwned"))), tmp_path / "w.pt")
    policy = scripted_policy(tmp_path / "honest.pt", 0, 1)
    assert (
        main(["eval", "--policy", str(policy), "--suite", tiny, "--out", str(tmp_path / "r.json"), "--no-progress"])
        == 0
    )
    root = tmp_path / "lb"
    _direct_row(root, tiny, "ts-row", Results.load(tmp_path / "r.json"), (tmp_path / "w.pt").read_bytes(), ".pt")
    capsys.readouterr()  # (eval's hold line and no-card warning on stderr)
    err = one_line_error(capsys, ["leaderboard", "--root", str(root), "--verify"])
    assert "ts-row.json" in err and "artifact" in err
    assert not (tmp_path / "pwned").exists()


def test_a_stored_artifact_failing_mid_run_names_row_scenario_and_step(tmp_path, tiny, capsys, scripts):
    pytest.importorskip("onnxruntime")
    net = scripts.Bad(0)  # mode 7 on real observations, exported to ONNX through the sandbox by submit's path
    from overtakezoo.benchmark.run.artifacts import Artifact
    from overtakezoo.benchmark.run.policy import boxed

    torch.jit.save(torch.jit.script(net), tmp_path / "bad.pt")
    box = boxed(
        Artifact("torchscript", (tmp_path / "bad.pt").read_bytes()),
        suites.load_suite(tiny).config,
        "bad",
        allow_code=True,
    )
    onnx_bytes = box.inner.export_onnx(D)
    box.inner.close()
    honest = scripted_policy(tmp_path / "honest.pt", 0, 1)
    assert (
        main(["eval", "--policy", str(honest), "--suite", tiny, "--out", str(tmp_path / "r.json"), "--no-progress"])
        == 0
    )
    root = tmp_path / "lb"
    _direct_row(root, tiny, "seven", Results.load(tmp_path / "r.json"), onnx_bytes, ".onnx")
    capsys.readouterr()  # (eval's hold line and no-card warning on stderr)
    err = one_line_error(capsys, ["leaderboard", "--root", str(root), "--verify"])
    assert err.startswith("error: submissions/tiny/seven.json: ") and "step 0" in err and "scenario" in err
    assert "returned mode 7" in err


def test_a_box_loads_code_only_when_asked(tmp_path, scripts):
    """What verify builds (no allow_code) refuses TorchScript before any process starts."""
    from overtakezoo.benchmark.run.sandbox import PolicyFailure, SandboxedPolicy

    torch.jit.save(torch.jit.script(scripts.Writer(str(tmp_path / "pwned"))), tmp_path / "w.pt")
    with pytest.raises(PolicyFailure, match="not a stored data format"):
        SandboxedPolicy("torchscript", (tmp_path / "w.pt").read_bytes(), EnvConfig())
    assert not (tmp_path / "pwned").exists()


# ----------------------------------------------------------------------------- train --resume
@pytest.mark.parametrize("algo", ["dqn", "ppo"])
def test_resume_never_unpickles_a_checkpoint(tmp_path, capsys, algo):
    marker = tmp_path / f"pwned-{algo}"
    ckpt = tmp_path / "checkpoint.pt"
    torch.save({"algo": algo, "net": Plant(marker), "iter": 1, "infos": {}}, ckpt)
    err = one_line_error(
        capsys, ["train", algo, "--resume", str(ckpt), "--out", str(tmp_path / "run"), "--steps", "64", "--no-progress"]
    )
    assert "checkpoint" in err and not marker.exists()
