"""``shapebench init``: an editable copy of the built-in configs, for users of an installed
package (a wheel has no ``configs/`` folder to edit)."""

from __future__ import annotations

from pathlib import Path

import click

from shapebench.cli.app import cli


@cli.command()
@click.argument("directory", default=".", type=click.Path(file_okay=False, path_type=Path))
@click.option("--force", is_flag=True, help="Overwrite files that are already there.")
def init(directory: Path, force: bool) -> None:
    """Write the built-in profiles and an example sweep into DIRECTORY/configs.

    Commands run from DIRECTORY read configs/ there before the built-in copies, one file at a
    time: edit configs/profiles/standard.yaml to change what the default profile trains, or copy
    configs/sweeps/default.yaml to make a sweep of your own. A file that is already there is
    kept (it may hold your edits) unless --force. An edited profile changes the checkpoint and
    cell keys of what it configures, so shipped reference weights no longer match them.

    \b
    Examples:
      shapebench init                 # into ./configs
      shapebench init my-study && cd my-study && shapebench sweep configs/sweeps/default.yaml
    """
    from shapebench.config import write_editable_configs

    written, kept = write_editable_configs(directory, overwrite=force)
    for path in written:
        click.echo(f"wrote {path}")
    for path in kept:
        click.echo(f"kept  {path} (already there; --force overwrites it)")
    here = "" if directory.resolve() == Path.cwd().resolve() else f"cd {directory} && "
    click.echo(f"next: {here}shapebench sweep configs/sweeps/default.yaml")
