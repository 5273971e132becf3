"""The wheel a user installs holds every module and data file of the three layers, found by setup.py's
package discovery (no hand-kept list), and works outside the repository: suites, schemas and the
zoo's weights load from the installed package."""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
LAYERS = ("envs", "zoo", "benchmark")


def _project_files() -> list[str]:
    """What a clone holds: tracked files and new ones git does not ignore."""
    out = subprocess.run(
        ["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z"],
        cwd=ROOT,
        capture_output=True,
        check=True,
    ).stdout
    return [f for f in out.decode().split("\0") if f and (ROOT / f).is_file()]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("needs the project's git checkout")
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    for name in _project_files():  # a copy: building writes build/ and *.egg-info beside the sources
        (src / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / name, src / name)
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "-w", str(tmp / "out"), "."],
        cwd=src,
        check=True,
        capture_output=True,
    )
    (whl,) = (tmp / "out").glob("overtakezoo-*.whl")
    return whl


def test_the_wheel_holds_every_module_and_data_file_of_the_layers(wheel: Path) -> None:
    names = set(zipfile.ZipFile(wheel).namelist())
    layer_files = [f for f in _project_files() if f.split("/")[0] in LAYERS]
    assert any(f.endswith(".toml") for f in layer_files) and any(f.endswith(".npz") for f in layer_files)
    missing = [f for f in layer_files if f"overtakezoo/{f}" not in names]
    assert not missing, f"setup.py's package discovery or pyproject's package-data misses {missing[:5]}"
    assert not [n for n in names if n.startswith(("overtakezoo/tests/", "overtakezoo/scripts/", "tests/"))]


def test_the_unpacked_wheel_runs_outside_the_repository(wheel: Path, tmp_path: Path) -> None:
    site = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(site)
    code = (
        "import overtakezoo.envs as e, overtakezoo.zoo as z, overtakezoo.benchmark.cli\n"
        "from overtakezoo.envs.suites import load_suite\n"
        "from overtakezoo.benchmark.results.schema import SCHEMA_PATH\n"
        f"assert e.__file__.startswith({str(site)!r}), e.__file__\n"
        "s = load_suite('table1'); assert s.count == 3000 and SCHEMA_PATH.is_file()\n"
        "z.load('rule-fsm'); print('ok')\n"
    )
    # -I: isolated, so neither the repository nor the editable install is on the path
    env_path = [str(site), *[p for p in sys.path if "site-packages" in p]]
    out = subprocess.run(
        [sys.executable, "-I", "-c", f"import sys; sys.path[:0] = {env_path!r}\n{code}"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
    )
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr[-2000:]
