"""The failure board (benchmark/failures/board.py): cross-table, failure suites, maps."""

import json

import numpy as np
import pytest

pytest.importorskip("cma")

from overtakezoo.benchmark.errors import UserError  # noqa: E402
from overtakezoo.benchmark.failures import board  # noqa: E402
from overtakezoo.envs.suites import load_suite  # noqa: E402

ROWS = ["always-overtake", "always-follow"]


@pytest.fixture(scope="module")
def boards(tmp_path_factory):
    d = tmp_path_factory.mktemp("board")
    # (no oracle column here: it simulates the future of every row, the slow part of a board)
    kw = dict(budget=48, deciders=ROWS, suites=("table1",), maps=False, upper_bounds=False)
    one = board.write_failure_board(d / "one", jobs=1, **kw)
    two = board.write_failure_board(d / "two", jobs=2, **kw)
    return d, one, two


def test_workers_give_the_same_board(boards):
    d, one, two = boards
    for name in ("board.json", "README.md", "cross-table1.png"):
        assert (d / "one" / name).read_bytes() == (d / "two" / name).read_bytes(), name


def test_cross_table(boards):
    d, one, _ = boards
    doc = json.loads((d / "one" / "board.json").read_text())
    assert doc["columns"] == ROWS
    assert board.board_columns(ROWS) == ROWS + ["oracle"]
    assert "oracle" not in board.board_deciders() and not any("+" in n for n in board.board_deciders())
    rows = doc["suites"]["table1"]["rows"]
    assert rows["always-follow"]["distinct"] == 0 and rows["always-follow"]["file"] is None
    for r in ("always-overtake",):
        cells = rows[r]["cells"]
        assert cells[r]["crash"] == cells[r]["n"] == rows[r]["kept"] > 0  # its own failures crash again
        assert cells["always-follow"]["crash"] == 0
        suite = load_suite(d / "one" / rows[r]["file"])  # a failure suite like any
        assert suite.count == rows[r]["kept"]
    text = (d / "one" / "README.md").read_text()
    assert "| always-follow | 0 in 48 | 0 in 48 | - | none found |" in text
    assert "cross-table1.png" in text and "do not edit" in text


def test_refuses_to_replace_another_folder(tmp_path):
    (tmp_path / "mine.txt").write_text("keep")
    with pytest.raises(UserError, match="is not a failure board"):
        board.write_failure_board(tmp_path, budget=8, deciders=["always-follow"], suites=("table1",), maps=False)
    assert (tmp_path / "mine.txt").read_text() == "keep"


def test_failure_map():
    suite = load_suite("table1")
    space, unit, xs, ys = board.map_points(suite, 0, resolution=5, draws=2)
    assert unit.shape == (50, space.size) and xs[0] > 20 and ys[-1] < 25
    vals = space.values(unit)
    assert np.allclose(np.unique(vals["oncoming_gap"]), xs) and np.allclose(np.unique(vals["lead_gap"]), ys)
    out = board._map_job(("table1", "always-overtake", {"oncoming_gap": [50.0], "lead_gap": [10.0]}, 48, 5, 2, 3))
    assert out["png"].startswith(b"\x89PNG") and out["cells_failing"] > 0
