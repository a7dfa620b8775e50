"""The wheel holds the package's data (the anatomies, the study files, the shipped lesion tables
with their digests, the model files): a first run on a fresh machine reads them from the install,
never from the repository. Built with pip as a user would (setuptools' own build), no warnings
about folders left out of the package list."""

import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _in_wheel(path: Path) -> str:
    """A repository file's name in the wheel (the layers install under ``ballchain/``)."""
    path = str(path)
    return path if path.startswith("ballchain/") else "ballchain/" + path


@pytest.mark.slow
def test_the_wheel_ships_every_data_file_and_setuptools_names_every_package(tmp_path):
    out = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-v", "-w", str(tmp_path), str(ROOT)],
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    log = out.stdout + out.stderr
    assert "is absent from the `packages` configuration" not in log, [l for l in log.splitlines() if "absent" in l]
    (wheel,) = tmp_path.glob("ballchain-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    expected = {"ballchain/drake_models/package.xml", "ballchain/drake_models/station.scenarios.yaml",
                "ballchain/rl/baseline_weights.json"}
    for folder, pattern in (("drake_models/anatomies", "*"), ("ballchain/studies", "*.yaml"),
                            ("drake_models/generated/lesion_surrogate", "*/*"),
                            ("drake_models/generated/lesion_dwell", "*/*")):
        files = [p for p in (ROOT / folder).glob(pattern) if p.is_file()]
        assert files, folder
        expected |= {_in_wheel(p.relative_to(ROOT)) for p in files}
    assert expected <= names, sorted(expected - names)
    assert any(n.endswith("lesion_table.npz") for n in names) and any(n.endswith("files.sha1") for n in names)
