"""The official datasets: the recipe table regenerates a registry, `download` rebuilds a
dataset offline whose content hash equals the registry's (a tampered hash is refused), and the
download tries the mirrors in order on a real 127.0.0.1 server, resuming from a .part file."""

from __future__ import annotations

import json
import shutil
import socket
from pathlib import Path

import numpy as np
import pytest
from test_datasets import RangeHandler, load_minari, server  # noqa: F401 - server: a fixture

from overtakezoo.benchmark.cli import main
from overtakezoo.benchmark.datasets.recipes import RECIPES_FILE, read_recipes

RECIPES = """
version = 0
chunk_size = 4096
mirrors = ["{base}/{{archive}}"]
suites = [{{ suite = "table1-train", env = "t1", count = 6 }}]

[levels.random]
name = "random"
decider = "always-follow"
epsilon = 1.0
seed = 3

[levels.medium]
decider = "rule-fsm"
epsilon = 0.1
seed = 0

[levels.mixed]
name = "mixed"
interleave = ["random", "medium"]
"""
MEDIUM, MIXED, RANDOM = "overtakezoo/t1/rule-fsm-v0", "overtakezoo/t1/mixed-v0", "overtakezoo/t1/random-v0"


def dead_url() -> str:
    """A 127.0.0.1 port nobody listens on (connection refused)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    return f"http://127.0.0.1:{port}"


@pytest.fixture
def published(home, monkeypatch):  # noqa: F811 - the imported fixture
    """A registry regenerated from a small recipe table (6 scenarios), then an empty cache."""
    recipes = home / "recipes.toml"
    recipes.write_text(RECIPES.format(base=dead_url()))
    assert (
        main(["dataset", "regenerate", "--recipes", str(recipes), "--archives", str(home / "release"), "--no-progress"])
        == 0
    )
    reg = json.loads((home / "registry.json").read_text())["datasets"]
    built = home / "home" / "datasets"
    monkeypatch.setenv("OVERTAKEZOO_HOME", str(home / "fresh"))
    return reg, built


def test_regenerate_records_recipes_and_build_reproduces_offline(published, home, capsys):
    reg, built = published
    assert sorted(reg) == sorted([MIXED, MEDIUM, RANDOM])
    e = reg[MEDIUM]
    assert e["level"] == "medium" and e["episodes"] == 6 and len(e["content_sha256"]) == 64
    assert e["recipe"]["suite"] == "table1-train" and len(e["recipe"]["suite_sha256"]) == 64
    assert e["recipe"]["policies"] == [
        {"decider": "rule-fsm", "decider_version": "1", "weights_sha256": None, "epsilon": 0.1, "seed": 0}
    ]
    assert e["mirrors"][0].endswith("/overtakezoo__t1__rule-fsm-v0.tar.gz")
    archive = home / "release" / "overtakezoo__t1__rule-fsm-v0.tar.gz"
    assert archive.stat().st_size == e["size"]
    # The outcome shares are the episodes' own last outcomes.
    ds = load_minari(built, MEDIUM)
    ends = [
        ("running", "success", "crash", "timeout", "offroad")[int(ep.infos["outcome"][-1])]
        for ep in ds.iterate_episodes()
    ]
    assert e["outcomes"] == {k: round(ends.count(k) / len(ends), 4) for k in set(ends)}

    # Offline with --no-build: the only mirror refuses the connection; one error line says how to rebuild.
    capsys.readouterr()
    assert main(["dataset", "download", MEDIUM, "--no-build", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and err.count("\n") == 1 and "--no-build" in err and "unreachable" in err
    # By default the rebuild follows, hash checked, and each step is said.
    assert main(["dataset", "download", MEDIUM, "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "trying http" in out and "failed:" in out and "rebuilding it from the registry's recipe" in out
    assert f"content hash matches the registry's ({e['content_sha256'][:16]}" in out and "installed" in out

    from overtakezoo.benchmark.datasets.store import content_sha256

    fresh = home / "fresh" / "datasets"
    ds = load_minari(fresh, MEDIUM)  # Minari's own loader reads the rebuild
    assert ds.total_episodes == 6 and content_sha256(ds) == e["content_sha256"]
    first = load_minari(built, MEDIUM)  # the regenerated copy: the same arrays
    for a, b in zip(first.iterate_episodes(), ds.iterate_episodes(), strict=True):
        assert np.array_equal(a.observations, b.observations) and np.array_equal(a.actions, b.actions)

    # The mixed dataset alternates its components' episodes exactly.
    assert main(["dataset", "download", MIXED, "--no-progress"]) == 0
    mixed = list(load_minari(fresh, MIXED).iterate_episodes())
    parts = [list(load_minari(built, n).iterate_episodes()) for n in (RANDOM, MEDIUM)]
    for i, ep in enumerate(mixed):
        src = parts[i % 2][i]
        assert np.array_equal(ep.observations, src.observations) and np.array_equal(ep.actions, src.actions)
    assert {int(a) for a in np.concatenate([ep.actions for ep in mixed[::2]])} == {0, 1, 2}  # random modes


def test_tampered_content_hash_or_other_versions_are_refused(published, home, capsys):
    reg, _ = published
    path = home / "registry.json"

    def edit(change):
        data = json.loads(path.read_text())
        change(data["datasets"][MEDIUM])
        path.write_text(json.dumps(data))

    edit(lambda e: e.update(content_sha256="0" * 64))
    capsys.readouterr()
    assert main(["dataset", "download", MEDIUM, "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "does not reproduce" in err and "nothing was installed" in err and err.count("\n") == 1
    datasets = home / "fresh" / "datasets" / "overtakezoo" / "t1"
    assert not datasets.exists() or list(datasets.iterdir()) == []  # no dataset, no staging left behind

    # A malformed list of other CPUs' rebuild hashes is a registry error; a listed hash that the rebuild
    # gives is accepted (the same recipe under another CPU's float kernels: store.py).
    edit(lambda e: e.update(rebuild_sha256=["xyz"]))
    assert main(["dataset", "download", MEDIUM, "--no-progress"]) == 2
    assert "rebuild_sha256 (a list of 64 hex)" in capsys.readouterr().err
    edit(lambda e: e.update(rebuild_sha256=["1" * 64, reg[MEDIUM]["content_sha256"]]))
    assert main(["dataset", "download", MEDIUM, "--no-progress"]) == 0
    assert f"content hash matches the registry's ({reg[MEDIUM]['content_sha256'][:16]}" in capsys.readouterr().out
    shutil.rmtree(home / "fresh" / "datasets")
    edit(lambda e: e.pop("rebuild_sha256"))

    edit(lambda e: e.update(content_sha256=reg[MEDIUM]["content_sha256"]) or e["recipe"].update(suite_sha256="1" * 64))
    assert main(["dataset", "download", MEDIUM, "--no-progress"]) == 2
    assert "another version" in capsys.readouterr().err
    edit(
        lambda e: (
            e["recipe"].update(suite_sha256=reg[MEDIUM]["recipe"]["suite_sha256"])
            or e["recipe"]["policies"][0].update(decider_version="99")
        )
    )
    assert main(["dataset", "download", MEDIUM, "--no-progress"]) == 2
    assert "the recipe used v99" in capsys.readouterr().err


def test_mirrors_in_order_with_resume(published, home, server, capsys):  # noqa: F811
    reg, _ = published
    blob = (home / "release" / "overtakezoo__t1__rule-fsm-v0.tar.gz").read_bytes()
    RangeHandler.files["/ds.tar.gz"] = blob
    data = json.loads((home / "registry.json").read_text())
    data["datasets"][MEDIUM]["mirrors"] = [dead_url() + "/ds.tar.gz", server + "/ds.tar.gz"]
    (home / "registry.json").write_text(json.dumps(data))
    part = home / "fresh" / "downloads" / "overtakezoo__t1__rule-fsm-v0.tar.gz.part"
    part.parent.mkdir(parents=True)
    part.write_bytes(blob[: len(blob) // 2])  # an earlier, interrupted download
    assert main(["dataset", "download", MEDIUM, "--no-progress"]) == 0
    assert RangeHandler.seen == [f"bytes={len(blob) // 2}-"]  # the dead mirror skipped, the live one resumed
    assert not part.exists()
    from overtakezoo.benchmark.datasets.store import content_sha256

    assert content_sha256(load_minari(home / "fresh" / "datasets", MEDIUM)) == reg[MEDIUM]["content_sha256"]


def test_pack_is_byte_deterministic_and_recipe_table_is_checked(home, tmp_path, capsys):  # noqa: F811
    name = "overtakezoo/t1/p-v0"
    assert (
        main(
            [
                "dataset",
                "build",
                "--suite",
                "table1-train",
                "--decider",
                "always-follow",
                "--count",
                "2",
                "--name",
                name,
            ]
        )
        == 0
    )
    capsys.readouterr()
    shas = []
    for out in ("a.tar.gz", "b.tar.gz"):
        assert main(["dataset", "pack", name, "--out", str(tmp_path / out)]) == 0
        shas.append(json.loads(capsys.readouterr().out.split("\n", 1)[1])[name]["sha256"])
    assert shas[0] == shas[1] and (tmp_path / "a.tar.gz").read_bytes() == (tmp_path / "b.tar.gz").read_bytes()

    table = read_recipes(RECIPES_FILE)  # the shipped table is valid, with the four levels
    assert set(table["levels"]) == {"random", "medium", "expert", "mixed"}
    # The expert is the best learned member by the leaderboard's OvertakeZoo score.
    from overtakezoo.benchmark.leaderboard.generate import LEARNED

    scores = json.loads((Path(__file__).resolve().parents[2] / "leaderboards" / "index.json").read_text())
    learned = {k: v["value"] for k, v in scores["headline"]["scores"].items() if k in LEARNED}
    assert table["levels"]["expert"]["decider"] == max(learned, key=learned.get)
    bad = tmp_path / "bad.toml"
    bad.write_text(RECIPES.format(base="http://x").replace("epsilon = 0.1", "epsilon = 0.1\nepsilom = 2"))
    assert main(["dataset", "regenerate", "--recipes", str(bad), "--no-progress"]) == 2
    assert "levels.medium: unknown key(s) ['epsilom']" in capsys.readouterr().err


def test_shipped_registry_names_the_readme_example():
    from overtakezoo.benchmark.datasets.registry import REGISTRY_FILE, load_registry

    reg = load_registry(REGISTRY_FILE)
    e = reg["overtakezoo/table1/rule-fsm-v0"]
    assert e["level"] == "medium" and e["recipe"]["suite"] == "table1-train" and e["content_sha256"]
    assert {x["level"] for x in reg.values()} >= {"random", "medium", "expert", "mixed"}


def test_regenerate_and_download_help_have_examples(capsys):
    for argv in (["dataset", "regenerate", "--help"], ["dataset", "download", "--help"]):
        with pytest.raises(SystemExit) as exc:
            main(argv)
        assert exc.value.code == 0 and "examples:" in capsys.readouterr().out
