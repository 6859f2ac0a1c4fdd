"""The wheel holds the four packages, the scenario data and the ``vmp`` command."""

import os
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


def _files(folder: Path) -> set[str]:
    return {p.relative_to(folder).as_posix() for p in folder.rglob("*")}


def test_a_run_writes_nothing_inside_the_installed_package(tmp_path):
    # Installed as pip installs it (a wheel, byte code compiled), then run: the compiled
    # kernels go to the cache folder, never beside the package's modules, where an editable
    # install after it would find a stale namespace package.
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
         "-w", str(tmp_path / "wheel"), str(ROOT)],
        check=True, capture_output=True, cwd=tmp_path,
    )
    (wheel,) = (tmp_path / "wheel").glob("vmp_slam-*.whl")
    site = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target",
                    str(site), str(wheel)], check=True, capture_output=True, cwd=tmp_path)
    before = {pkg: _files(site / pkg) for pkg in ("vmp", "milestones", "drivers", "viz")}
    cache = tmp_path / "kernels"
    env = {**os.environ, "PYTHONPATH": str(site), "VMP_CACHE_DIR": str(cache)}
    env.pop("NUMBA_CACHE_DIR", None)
    done = subprocess.run(
        [sys.executable, "-c", "import sys, vmp; from vmp.cli import main; "
         f"assert vmp.__file__.startswith({str(site)!r}), vmp.__file__; "
         "sys.exit(main(sys.argv[1:]))", "map", "office", "--scans", "40", "--out",
         str(tmp_path / "results")], capture_output=True, text=True, cwd=tmp_path, env=env)
    assert done.returncode == 0, done.stderr
    assert "compiling kernels once, cached in " + str(cache) in done.stderr
    for pkg, files in before.items():
        assert _files(site / pkg) == files, f"new files under the installed {pkg}/"
    assert any(p.suffix == ".nbi" for p in cache.rglob("*"))  # they went to the cache
