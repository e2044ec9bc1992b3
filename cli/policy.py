"""`behave policy list`: the bundled policies, by the names `--policy` takes, with their model card."""

from __future__ import annotations

import re
from pathlib import Path

import typer
from rich.console import Console
from rich.table import Table

import behaviors
from behaviors.cli.group import QuickHelpGroup

PRETRAINED = Path(behaviors.__file__).parent / "pretrained"
"""behaviors.learn.policy.PRETRAINED, named here so that listing needs no torch."""
MODEL_CARD = PRETRAINED / "MODEL_CARD.md"
RESULT_LINES = ("evaluation", "screens", "shipped checkpoint")
"""The model card's bullet that `policy list` shows per policy: the first of these a section has."""

app = typer.Typer(help="The bundled policies (names that --policy takes).", cls=QuickHelpGroup)


def model_card_lines(text: str) -> dict[str, tuple[str, str]]:
    """Per policy file stem: its model card heading and its first RESULT_LINES bullet ("" if none)."""
    cards: dict[str, tuple[str, str]] = {}
    for section in re.split(r"^## ", text, flags=re.MULTILINE)[1:]:
        heading, _, body = section.partition("\n")
        match = re.search(r"\((\w+)\.pt\)\s*$", heading)
        if match is None:
            continue
        title = heading[: match.start()].strip()
        bullets = re.findall(r"^- ([^\n]*)", body, flags=re.MULTILINE)
        result = next((b for start in RESULT_LINES for b in bullets if b.startswith(start)), "")
        cards[match.group(1)] = (title, result)
    return cards


@app.command("list")
def list_policies() -> None:
    """Each bundled policy: the name --policy takes, its model card's title and result line."""
    cards = model_card_lines(MODEL_CARD.read_text(encoding="utf-8")) if MODEL_CARD.is_file() else {}
    table = Table(title="behave policies (behaviors/pretrained/MODEL_CARD.md)")
    for column in ("name", "model card", "result"):
        table.add_column(column)
    for path in sorted(PRETRAINED.glob("*.pt")):
        title, result = cards.get(path.stem, ("(not in the model card)", ""))
        table.add_row(path.stem, title, result)
    Console().print(table)
