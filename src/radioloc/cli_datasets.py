"""``radioloc datasets list | fetch NAME | export NAME``: the public data sets on the command line.

Mounted on the main command line by ``app.add_typer(datasets_app, name="datasets")``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.console import Console
from rich.table import Table

from radioloc.core.errors import RadiolocError

datasets_app = typer.Typer(
    help="Public data sets: which are present, fetch one from its origin, export one to the "
         "`radioloc locate` formats.",
    no_args_is_help=True, add_completion=False, pretty_exceptions_enable=False)
_err = Console(stderr=True)


def _console() -> Console:
    from radioloc.report.tables import wide_console

    return wide_console()


def _fail(exc: Exception) -> None:
    _err.print(f"[bold red]error:[/bold red] {exc}", highlight=False, soft_wrap=True)
    raise typer.Exit(code=2)


@datasets_app.command("list")
def list_datasets() -> None:
    """List the data sets: present (and where), license, checksums, what export writes."""
    from radioloc.io.datasets import data_roots, status

    table = Table("name", "present", "license", "checksums", "export", title="radioloc data sets",
                  title_justify="left")
    for row in status().itertuples():
        present = f"[green]yes[/green] {row.path}" if row.present else "[yellow]no[/yellow]"
        note = f"\n[dim]{row.note}[/dim]" if row.note else ""
        table.add_row(f"{row.name}\n[dim]{row.title}[/dim]{note}", present, row.license,
                      row.checksums, row.exports or "-")
    con = _console()
    con.print(table)
    con.print(f"searched: {', '.join(str(r) for r in data_roots())} "
              "(set RADIOLOC_DATA to use one folder only)", highlight=False)


@datasets_app.command("fetch")
def fetch_dataset(
    name: Annotated[str, typer.Argument(help="Data set name or alias (see `radioloc datasets list`).")],
    dest: Annotated[Optional[Path], typer.Option(help="Data root to write into (default: $RADIOLOC_DATA, else the platform cache).")] = None,
    verify: Annotated[bool, typer.Option("--verify/--no-verify", help="Check the pinned checksums (--no-verify accepts unchecked files).")] = True,
    base_url: Annotated[Optional[str], typer.Option(help="Download from this base URL instead of the pinned origin (a mirror or file:// folder).")] = None,
) -> None:
    """Download a data set from its pinned public origin and check every file's checksum."""
    from radioloc.io.datasets import fetch

    try:
        folder = fetch(name, dest=dest, verify=verify, base_url=base_url,
                       log=lambda m: _err.print(m, highlight=False))
    except RadiolocError as exc:
        _fail(exc)
    _console().print(f"{name}: {folder}", highlight=False)


@datasets_app.command("export")
def export_dataset(
    name: Annotated[str, typer.Argument(help="hanyang, kolakowski, smartloc, ujiindoorloc or wifi-rtt.")],
    out: Annotated[Path, typer.Option(help="Output folder.")] = Path("export"),
    fmt: Annotated[str, typer.Option("--format", help="csv or parquet (Parquet needs pyarrow).")] = "csv",
    run: Annotated[str, typer.Option(help="hanyang: run CONDITION/TRAJECTORY/CASE, e.g. LOS/A/1.")] = "LOS/A/1",
    epoch_s: Annotated[float, typer.Option(help="hanyang: 0 (default) writes every range at its own time, as the anchors answer (for ekf-track, pf); > 0: anchors' ranges sampled on epochs of this length, all anchors per epoch (for gn, e.g. 0.1).")] = 0.0,
    tag_height: Annotated[Optional[float], typer.Option(help="hanyang: project ranges to 2-D with the tag at this height (m).")] = None,
    building: Annotated[int, typer.Option(help="ujiindoorloc: BUILDINGID.")] = 0,
    floor: Annotated[int, typer.Option(help="ujiindoorloc: FLOOR.")] = 0,
    min_detections: Annotated[int, typer.Option(help="ujiindoorloc: keep access points detected at least this often.")] = 20,
    data: Annotated[Optional[Path], typer.Option("--data", help="The data set's folder (default: looked up in $RADIOLOC_DATA, the cache, shared/data), e.g. a full copy of the published set.")] = None,
    venue: Annotated[str, typer.Option(help="wifi-rtt: a venue folder of raw_data/ (Canteen, 'Conference Room', Library here; any venue of the published set with --data).")] = "Canteen",
    circle: Annotated[str, typer.Option(help="wifi-rtt: circle folder of the venue, e.g. 1.")] = "1",
    rss: Annotated[bool, typer.Option("--rss", help="wifi-rtt: also write the RSS rows.")] = False,
    phone_std: Annotated[bool, typer.Option("--phone-std", help="wifi-rtt: write the phone's reported range std as the std column.")] = False,
    heading: Annotated[bool, typer.Option("--heading", help="wifi-rtt: also write the phone's azimuth as heading rows (compass frame: remove its offset to the map before tracking).")] = False,
    weights: Annotated[str, typer.Option(help="gnss-smartloc-berlin: the pseudoranges' std from the receiver's variance, the elevation or the C/N0.")] = "variance",
) -> None:
    """Write a data set in the `radioloc locate` formats (measurements, anchors, reference,
    and a fingerprint calibration file for the fingerprint sets)."""
    from radioloc.io.datasets import export, get

    try:
        ds = get(name)
        opts: dict = {"fmt": fmt, "root": data}
        if ds.name == "hanyang-uwb-outdoor":
            opts.update(run=run, epoch_s=epoch_s, tag_height_m=tag_height)
        elif ds.name == "ujiindoorloc":
            opts.update(building=building, floor=floor, min_detections=min_detections)
        elif ds.name == "gnss-smartloc-berlin":
            opts.update(weights=weights)
        elif ds.name == "wifi-rtt-haiyaoyu":
            opts.update(venue=venue, circle=circle, rss=rss, phone_std=phone_std, heading=heading)
        paths = export(ds.name, out, **opts)
    except RadiolocError as exc:
        _fail(exc)
    con = _console()
    for role, path in paths.items():
        con.print(f"{role:>12}: {path}", highlight=False)
