"""The wheel holds the four packages, the scenario data and the ``vmp`` command."""

import subprocess
import sys
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_wheel_contents(tmp_path):
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
         "-w", str(tmp_path), str(ROOT)],
        check=True, capture_output=True, cwd=tmp_path,
    )
    (wheel,) = tmp_path.glob("vmp_slam-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    for package in ("vmp", "milestones", "drivers", "viz", "scenarios"):
        assert f"{package}/__init__.py" in names
        # every module of the source tree, subpackages included, is in the wheel
        for module in (ROOT / package).rglob("*.py"):
            assert module.relative_to(ROOT).as_posix() in names
    for scenario in ("office", "corridor", "lab", "warehouse"):
        assert f"scenarios/{scenario}.yaml" in names
    assert not any(n.startswith(("tests/", "bench/")) for n in names)
    entry = next(n for n in names if n.endswith("entry_points.txt"))
    assert "vmp = vmp.cli:main" in zipfile.ZipFile(wheel).read(entry).decode()
