"""Every `pendsim ...` command shown in README.md and docs/*.md parses with the real argument
parser (so no page shows an option that does not exist or a value outside its range): each line of
a ```bash block, and each inline `pendsim ...` span without placeholders ("|", "[", "...")."""

import re
import shlex
from pathlib import Path

import pytest

from pendsim_bridge.cli import build_parser
from pendsim_bridge.options import UsageError

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def _commands() -> list[tuple[str, str]]:
    found = []
    for page in PAGES:
        for block in re.findall(r"```bash\n(.*?)```", page.read_text(), re.S):
            for line in block.splitlines():
                for part in re.split(r"&&|;|\|", line.split(" #")[0]):
                    words = shlex.split(part.strip().rstrip("&").strip())
                    if words and words[0] == "pendsim":
                        found.append((page.name, shlex.join(words[1:])))
        for span in re.findall(r"`(pendsim [^`]+)`", page.read_text()):
            if not any(mark in span for mark in ("|", "[", "...")):
                command = span.split(" > ")[0]  # a redirection is the shell's
                found.append((page.name, shlex.join(shlex.split(command)[1:])))
    return found


COMMANDS = _commands()


def page_mentions_in_prose(page: str, command: str) -> bool:
    """True if exactly this command appears as an inline span (`pendsim ...`) on the page."""
    text = next(p for p in PAGES if p.name == page).read_text()
    return f"`pendsim {command}`" in text


def test_the_pages_show_commands():
    assert len(COMMANDS) >= 2


@pytest.mark.parametrize(("page", "command"), COMMANDS)
def test_documented_command_parses(page, command, monkeypatch):
    # file arguments are not checked for existence here: only the options and their values
    monkeypatch.setattr("pendsim_bridge.options.input_file", lambda text: Path(text))
    monkeypatch.setattr("pendsim_bridge.options.mcap_file", lambda text: Path(text))
    parser = build_parser()
    words = shlex.split(command)
    if "--help" in words or "--version" in words:
        return  # these exit after printing: nothing more to check
    try:
        args = parser.parse_args(words)
    except UsageError as exc:
        if str(exc).startswith("the following arguments are required") and page_mentions_in_prose(page, command):
            return  # prose naming a command or an option ("`pendsim validate`"), not a full command line
        raise AssertionError(f"{page}: pendsim {command}: {exc}") from None
    assert callable(args.handler)
