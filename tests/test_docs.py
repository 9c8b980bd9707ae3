"""The docs name code that exists: every `module.py: name` of docs/architecture.md's walk through the code is a
module of the package that defines that name."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "stablemofusion"


def test_the_architecture_walkthrough_names_code_that_exists():
    text = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    refs = re.findall(r"`([\w/]+\.py): ([\w.]+)`", text)
    assert len(refs) >= 15
    missing = []
    for module, name in refs:
        path = PACKAGE / module
        if not path.is_file():
            missing.append(f"{module} (no such module)")
            continue
        last = name.split(".")[-1]
        if not re.search(rf"^\s*(def|class|async def) {last}\b|^{last}\s*=", path.read_text(encoding="utf-8"), re.M):
            missing.append(f"{module}: {name}")
    assert missing == []
    for module in set(re.findall(r"`([\w/]+\.py)`", text)):
        assert (PACKAGE / module).is_file() or (ROOT / module).is_file(), module
