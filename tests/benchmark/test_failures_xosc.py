"""OpenSCENARIO / OpenDRIVE export (benchmark/failures/xosc.py, `overtakezoo export-xosc`): the files
read back into the same scenario arrays, and pass the ASAM quality checkers."""

import os
import shutil
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("scenariogeneration")

from test_benchmark_cli import one_line_error  # noqa: E402

from overtakezoo.benchmark.cli import main  # noqa: E402
from overtakezoo.benchmark.failures.xosc import export, read_back  # noqa: E402
from overtakezoo.envs import Scenarios  # noqa: E402
from overtakezoo.envs.explicit import in_memory  # noqa: E402
from overtakezoo.envs.suites import load_suite  # noqa: E402


def assert_same(ref: Scenarios, got: Scenarios) -> None:
    for key, a in ref.to_arrays().items():
        b = getattr(got, key)
        assert a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b), (key, a, b)


@pytest.mark.parametrize(
    "name, indices",
    [
        ("table1", [0, 7]),
        ("adversarial", [3]),
        ("occluded", [1]),
        ("dense", [2]),
        ("oncoming-4", [5]),
        ("duel", [0]),
        ("platoon", [4]),
    ],
)
def test_round_trip(tmp_path, name, indices):
    suite = load_suite(name)
    paths = export(suite, tmp_path, indices)
    ref = suite.scenarios().take(np.array(indices))
    for i, (k, path) in enumerate(zip(indices, paths, strict=True)):
        got, meta = read_back(path)
        assert_same(ref.take(slice(i, i + 1)), got)
        assert meta["overtakezoo.suite_hash"] == suite.hash and meta["overtakezoo.index"] == str(k)
        header = ET.parse(path).getroot().find("FileHeader")
        assert suite.hash in header.get("description") and f"scenario {k} of {suite.count}" in header.get("description")
        assert header.get("revMajor") == "1" and header.get("revMinor") == "2"


def test_scripted_speed_changes_and_padding_round_trip(tmp_path):
    # A desired speed other than the start speed becomes a speed action at the start; a padded
    # batch (absent NPC slots, as a failure suite with several counts has) keeps its slot layout.
    suite = load_suite("adversarial")
    sc = Scenarios.concat([suite.scenarios().take(np.arange(2)), load_suite("oncoming-4").scenarios().take([0])])
    sc.npc_v_des[:, 0] += 0.5
    paths = export(in_memory(suite, sc), tmp_path)
    for i, path in enumerate(paths):
        got, _ = read_back(path)
        assert_same(sc.take(slice(i, i + 1)), got)
    assert "npc_0_to_desired_speed" in paths[0].read_text() and "npc_0_speed_up" in paths[0].read_text()


def test_export_is_the_same_bytes_every_time(tmp_path):
    suite = load_suite("table1")
    a = export(suite, tmp_path / "a", [3])[0]
    b = export(suite, tmp_path / "b", [3])[0]
    assert a.read_bytes() == b.read_bytes()
    assert a.with_suffix(".xodr").read_bytes() == b.with_suffix(".xodr").read_bytes()


def test_cli_exports_a_failure_file(tmp_path, capsys):
    pytest.importorskip("cma")
    f = tmp_path / "f.toml"
    assert (
        main(
            [
                "search",
                "--decider",
                "always-overtake",
                "--suite",
                "table1",
                "--budget",
                "32",
                "--out",
                str(f),
                "--no-progress",
            ]
        )
        == 0
    )
    out = tmp_path / "x"
    assert main(["export-xosc", "--failures", str(f), "--out", str(out)]) == 0
    failures = load_suite(f)
    files = sorted(out.glob("*.xosc"))
    assert len(files) == failures.count and len(list(out.glob("*.xodr"))) == failures.count
    got, meta = read_back(out / f"{failures.name}-0.xosc")
    assert_same(failures.scenarios().take([0]), got)
    assert meta["overtakezoo.suite_hash"] == failures.hash


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["--suite", "table1", "--index", "3000"], "--index 3000: out of range (suite 'table1' has scenarios 0-2999)"),
        (["--suite", "table1", "--index", "-1"], "--index -1: out of range"),
        (["--suite", "table1", "--index", "1", "--index", "1"], "an index is given twice"),
        (["--failures", "table1"], "lists no scenarios"),
        (["--suite", "nosuch"], "unknown suite 'nosuch'"),
    ],
)
def test_bad_input_is_one_error_line(tmp_path, capsys, argv, needle):
    err = one_line_error(capsys, ["export-xosc", *argv, "--out", str(tmp_path / "x")])
    assert needle in err
    assert not (tmp_path / "x").exists()


def test_unwritable_out_is_one_error_line(tmp_path, capsys):
    (tmp_path / "file").write_text("")
    err = one_line_error(capsys, ["export-xosc", "--suite", "table1", "--index", "0", "--out", str(tmp_path / "file")])
    assert "not a folder" in err


# ------------------------------------------------------------------ the ASAM quality checkers
def checker(name: str) -> str | None:
    folder = os.environ.get("OVERTAKEZOO_QC_BIN")
    return shutil.which(name, path=folder) if folder else shutil.which(name)


QC = {"xosc": ("qc_openscenario", "xoscBundle"), "xodr": ("qc_opendrive", "xodrBundle")}
needs_checkers = pytest.mark.skipif(
    not all(checker(exe) for exe, _ in QC.values()),
    reason="ASAM quality checkers (qc_openscenario, qc_opendrive) not found: asam-qc-opendrive 1.0 pins numpy<2, so "
    "install the [xosc-check] extra in an environment of its own and set OVERTAKEZOO_QC_BIN to its bin folder",
)


def run_checker(path: Path, kind: str, tmp_path: Path) -> ET.Element:
    exe, bundle = QC[kind]
    result = tmp_path / f"{path.name}.xqar"
    config = tmp_path / f"{path.name}.config.xml"
    config.write_text(
        f'<?xml version="1.0" encoding="UTF-8"?>\n<Config>\n  <Param name="InputFile" value="{path}"/>\n'
        f'  <CheckerBundle application="{bundle}">\n    <Param name="resultFile" value="{result}"/>\n'
        "  </CheckerBundle>\n</Config>\n"
    )
    done = subprocess.run([checker(exe), "-c", str(config)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    return ET.parse(result).getroot()


@needs_checkers
@pytest.mark.parametrize("name, index", [("table1", 0), ("adversarial", 3), ("duel", 0)])
def test_asam_checkers_find_no_issue(tmp_path, name, index):
    xosc = export(load_suite(name), tmp_path / "out", [index])[0]
    for path, kind, at_least in ((xosc, "xosc", 17), (xosc.with_suffix(".xodr"), "xodr", 22)):
        root = run_checker(path, kind, tmp_path)
        issues = [
            i.get("description") + ": " + " ".join(loc.get("description", "") for loc in i.iter("Locations"))
            for i in root.iter("Issue")
        ]
        assert issues == [], (kind, issues)
        checkers = list(root.iter("Checker"))
        completed = [c for c in checkers if c.get("status") == "completed"]
        assert len(completed) >= at_least, [(c.get("checkerId"), c.get("summary")) for c in checkers]
        assert all(c.get("status") in ("completed", "skipped") for c in checkers)
