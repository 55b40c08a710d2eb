"""``toosicubix schema``: the JSON Schema of the annotation file."""

from __future__ import annotations

import json

import click


@click.command("schema")
def schema_command() -> None:
    """Print the JSON Schema of the annotation file (format version 1).

    \b
    Example:
      toosicubix schema > annotations.schema.json
    """
    from toosicubix.annotations.schema import json_schema

    click.echo(json.dumps(json_schema(), indent=2))
