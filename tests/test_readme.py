"""The README stays true: its test command is what CI runs, and every scene key is documented."""
import re
from pathlib import Path

from jointsim.scene import key_table

ROOT = Path(__file__).resolve().parents[1]


def test_ci_runs_the_readme_test_command():
    readme = (ROOT / "README.md").read_text()
    commands = re.findall(r"```bash\n(.*?)\n```", readme.split("## Set-up")[1].split("##")[0],
                          re.S)
    assert len(commands) == 2, "the set-up is exactly two commands"
    ci = (ROOT / ".ci" / "run").read_text()
    assert commands[1].strip() in ci


def test_every_scene_key_is_documented_as_the_code_says():
    """Each key's row (default, unit, meaning) is the one ``jointsim keys`` prints: a
    missing key, a changed default or doc string cannot leave the README's table behind."""
    readme = set((ROOT / "README.md").read_text().splitlines())
    rows = [r for r in key_table().splitlines() if r.startswith("| `")]
    stale = [r.split("|")[1].strip() for r in rows if r not in readme]
    assert rows and not stale, f"README rows differ for {stale}; paste `jointsim keys`"
