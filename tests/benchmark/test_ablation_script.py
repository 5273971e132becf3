"""scripts/ablation.py keeps the variants it does not re-run, from the counts it recorded, only while
the suites are the ones they were measured on."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import pytest

from overtakezoo.benchmark.suite_groups import CORE
from overtakezoo.envs.suites import load_suite

SCRIPTS = Path(__file__).resolve().parents[2] / "scripts"


@pytest.fixture
def ablation(monkeypatch, tmp_path):
    monkeypatch.syspath_prepend(str(SCRIPTS))
    spec = importlib.util.spec_from_file_location("ablation_under_test", SCRIPTS / "ablation.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    (tmp_path / "docs").mkdir()
    monkeypatch.setattr(module, "ROOT", tmp_path)
    yield module
    sys.modules.pop("ablation_under_test", None)


def _seed(seed: int, success: int) -> dict:
    return {
        "seed": seed,
        "weights_sha256": f"{seed:064d}",
        "suites": {n: {"suite_sha256": load_suite(n).hash, "n": 1000, "success": success, "crash": 10} for n in CORE},
    }


def test_kept_variants_round_trip_through_the_report_and_drop_on_a_changed_suite(ablation, tmp_path):
    seeds = [_seed(0, 900), _seed(1, 800), _seed(2, 700)]
    results = {"dagger": [{**s, "train_cpu_s": 500.0, "offset": 0.0} for s in seeds]}
    md, doc = ablation.report(results, "python scripts/ablation.py --variants dagger")
    (tmp_path / "docs" / "ablation.json").write_text(json.dumps(doc))
    kept = ablation.kept_variants({"stack"}, [0, 1, 2])
    assert list(kept) == ["dagger"] and [k["suites"]["table1"]["success"] for k in kept["dagger"]] == [900, 800, 700]
    again, _ = ablation.report({"stack": results["dagger"], **kept}, "python scripts/ablation.py --variants stack")
    assert "`dagger` kept from `python scripts/ablation.py --variants dagger`" in again
    assert md.split("| dagger |")[1].split("\n")[0] == again.split("| dagger |")[1].split("\n")[0]  # same row
    assert ablation.kept_variants({"dagger"}, [0, 1, 2]) == {}  # re-run: not kept
    assert ablation.kept_variants(set(), [0, 1]) == {}  # other seeds: not kept
    doc["variants"]["dagger"]["runs"][1]["suites"]["dense"]["suite_sha256"] = "0" * 64  # the suite changed since
    (tmp_path / "docs" / "ablation.json").write_text(json.dumps(doc))
    assert ablation.kept_variants(set(), [0, 1, 2]) == {}
