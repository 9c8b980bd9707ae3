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


def _flat(text: str) -> str:
    """Markdown prose with its line breaks and runs of spaces as one space."""
    return re.sub(r"\s+", " ", text)


def test_the_readme_states_the_defaults_limits_and_formats_the_code_has():
    """The README's checkable facts read from the code: generate's default formats (table and --help), the one
    set of rules (limits.py), the default footskate mode, what convert reads and writes."""
    from stablemofusion.core import limits
    from stablemofusion.motion.files import MOTION_SUFFIXES

    readme = _flat((ROOT / "README.md").read_text(encoding="utf-8"))
    formats = limits.DEFAULT_FORMATS.split(",")
    assert f"[--format {limits.DEFAULT_FORMATS}]" in readme
    assert "joints/features " + ", ".join(f"`.{f}`" for f in formats) + " by default" in readme
    more = re.search(r" by default; ((?:`\w+`, )*`\w+`) with `--format`", readme)
    assert more and set(re.findall(r"`(\w+)`", more.group(1))) == set(limits.OUTPUT_FORMATS) - set(formats)
    assert (f"`seconds` more than 0 and at most {limits.MAX_SECONDS:g}, `steps` {limits.MIN_STEPS}-{limits.MAX_STEPS}, "
            f"`guidance` {limits.MIN_GUIDANCE:g}-{limits.MAX_GUIDANCE:g}, a timeline of at most {limits.MAX_SEGMENTS} "
            f"segments and {limits.MAX_SECONDS:g} s, prompts of at most {limits.MAX_PROMPT_CHARS} characters") in readme
    assert f"Footskate cleanup is `{limits.FOOTSKATE}` unless you say" in readme
    assert MOTION_SUFFIXES == (".npy", ".bvh")  # what convert reads, as the README says
    assert "from joints `.npy`, features `.npy` or `.bvh` to any of those or `.glb` (output only)" in readme


def test_the_documented_one_line_errors_and_warnings_are_the_ones_printed():
    """The README's example of a command that needs the train extra is what that command prints on the runtime
    install (torch blocked); docs/prompts.md quotes the out-of-domain warning in the code's words."""
    import subprocess
    import sys

    from stablemofusion.text.known import DomainCheck

    readme = _flat((ROOT / "README.md").read_text(encoding="utf-8"))
    quoted = re.search(r"\(`(smf: error: `smf ([\w-]+)` needs torch[^`]*)`\)", readme)
    assert quoted, "the README shows the one-line error of a command that needs the train extra"
    command = quoted.group(2)
    block = ("import sys; sys.modules['torch'] = None; from stablemofusion.cli.main import main; "
             f"sys.exit(main([{command!r}, '--help']))")
    done = subprocess.run([sys.executable, "-c", block], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and _flat(done.stderr).strip() == quoted.group(1).strip()
    prompts = _flat((ROOT / "docs" / "prompts.md").read_text(encoding="utf-8"))
    said = DomainCheck(0.33, (("walk", 0.9),), True).message("...")
    assert "smf: warning: " + said.split("; closest actions")[0] + "; closest actions it knows: ...`" in prompts
