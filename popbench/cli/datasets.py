"""``popbench datasets list | fetch | verify``: the registered datasets on disk."""

from __future__ import annotations

from typing import Annotated

import typer

from popbench.cli.errors import RuntimeFailure
from popbench.errors import PopbenchError

app = typer.Typer(
    help="List, download and verify the registered datasets.",
    epilog=(
        "Examples:\n\n"
        "  popbench datasets list\n\n"
        "  popbench datasets fetch intel m3500\n\n"
        "  POPBENCH_DATA=../shared/datasets popbench datasets verify"
    ),
    no_args_is_help=True,
)


# The datasets a command works on: registered names.
Names = Annotated[
    list[str] | None,
    typer.Argument(help="Registered names (see `popbench datasets list`).", show_default=False),
]


def _status_style(status: str) -> str:
    return {"ok": "green", "missing": "yellow"}.get(status, "red")


@app.command("list")
def datasets_list() -> None:
    """Show every registered dataset, its size and whether a verified copy is on disk."""
    from rich.console import Console
    from rich.table import Table

    from popbench import datasets

    status = dict(datasets.verify())
    table = Table(title=f"datasets (searched: {', '.join(map(str, datasets.search_dirs()))})")
    for column in ("name", "poses", "edges", "ground truth", "local", "description"):
        table.add_column(column, justify="right" if column in ("poses", "edges") else "left")
    for name, entry in datasets.DATASETS.items():
        here = status[entry.alias_of or name]
        short = here if here in ("ok", "missing") else "checksum mismatch"
        table.add_row(
            name,
            str(entry.poses),
            str(entry.edges),
            entry.ground_truth or "",
            f"[{_status_style(here)}]{short}[/]",
            entry.description,
        )
    Console().print(table)


@app.command("fetch")
def datasets_fetch(
    names: Names = None,
    fetch_all: Annotated[bool, typer.Option("--all", help="Fetch every registered file.")] = False,
) -> None:
    """Download datasets that are not on disk yet (with their ground truth) and verify them.

    Files go to $POPBENCH_DATA if set, else ~/.cache/popbench; a download is written to a
    temporary file, checked against its pinned sha256 and only then renamed into place.
    """
    from popbench import datasets

    if fetch_all:
        names = [name for name, entry in datasets.DATASETS.items() if entry.alias_of is None]
    if not names:
        raise PopbenchError("name one or more datasets (see `popbench datasets list`) or use --all")
    for name in names:
        typer.echo(f"{name}: ok {datasets.fetch(name)}")


@app.command("verify")
def datasets_verify(names: Names = None) -> None:
    """Check the sha256 of local copies of the named datasets (default: every registered file;
    nothing is downloaded); exit status 1 if any is bad."""
    from rich.console import Console
    from rich.table import Table

    from popbench import datasets

    report = datasets.verify(names or None)
    table = Table()
    table.add_column("name")
    table.add_column("status")
    for name, status in report:
        table.add_row(name, f"[{_status_style(status)}]{status}[/]")
    Console().print(table)
    bad = [name for name, status in report if status != "ok"]
    if bad:
        raise RuntimeFailure(
            f"{len(bad)} dataset file(s) missing or corrupt: {', '.join(bad)}; "
            f"run `popbench datasets fetch {' '.join(bad)}` (delete corrupt files first)"
        )
