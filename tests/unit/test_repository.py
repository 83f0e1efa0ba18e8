"""The repository stands on its own: a clone in any directory has everything its tests, docs and
defaults read. No tracked file names the sibling folder the project once sat beside, nor the design
notes that live only there."""

from __future__ import annotations

import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: built from parts, so that this file does not name what it forbids
SIBLING = "../" + "shared"
DESIGN_NOTES = ("DESIGN" + " §", "DESIGN" + ".md")


def _tracked_text_files() -> dict[str, str]:
    names = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()
    texts = {}
    for name in names:
        path = ROOT / name
        if not path.is_file() or path.stat().st_size > 2_000_000:
            continue
        try:
            texts[name] = path.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            continue
    return texts


def test_no_tracked_file_names_the_sibling_folder_or_the_design_notes():
    texts = _tracked_text_files()
    assert len(texts) > 200  # the tree was read
    offenders = sorted(name for name, text in texts.items() if SIBLING in text)
    assert offenders == [], f"{SIBLING} is named in {offenders}"
    cited = sorted(name for name, text in texts.items() if any(d in text for d in DESIGN_NOTES))
    assert cited == [], f"the design notes (not in this repository) are cited in {cited}"


def test_the_real_record_is_vendored_with_its_licence_and_source():
    folder = ROOT / "fixtures" / "real" / "yan9a-dbo"
    assert "MIT License" in (folder / "LICENSE").read_text()
    readme = (folder / "README.md").read_text()
    assert "yan9a/DiscreteBacklashOperator" in readme and "col 5" in readme
    rows = (folder / "Model_Vi_Do.dat").read_text().split("\n")
    assert len([r for r in rows if r.strip()]) == 8027
