"""The ``toosicubix`` command. Thin: parses options, calls the library, reports, sets the exit code.

One module per command group (``fit``, ``validate``, ``evaluate`` for ``eval``, ``simulate``, ``priors``,
``tune``, ``schema``); the options several commands share are declared once in :mod:`.options`. A command
is registered below with one line. Input errors (:class:`toosicubix.errors.InputError`) that a command lets
through are printed by the group with the file and JSON path or line.

Exit codes: 0 success; 1 a batch finished but some vehicles failed (validate: are not well determined);
2 bad input or usage.
"""

from __future__ import annotations

import os
import sys

# The commands run one process per core (``--jobs auto``): a BLAS thread pool in each only competes with the others,
# and starting one costs every process some 0.2 s of CPU. Set before numpy loads it; a value already set wins.
for _threads in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "VECLIB_MAXIMUM_THREADS"):
    os.environ.setdefault(_threads, "1")

import click

from toosicubix import __version__
from toosicubix.cli import (
    annotate,
    evaluate,
    export,
    fit,
    import_tools,
    learn,
    priors,
    render,
    schema,
    simulate,
    template,
    tune,
    validate,
)
from toosicubix.cli.options import EXIT_BAD_INPUT, EXIT_OK, EXIT_SOME_FAILED, BadInput, CommandGroup


@click.group(cls=CommandGroup, context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, "--version", prog_name="toosicubix")
def main() -> None:
    """ToosiCubix: 3D vehicle cuboids (rotation, position, size) from part clicks in one image.

    \b
    Typical use:
      toosicubix fit annotations.json          # writes toosicubix-out/label_2/*.txt, results.json
      toosicubix eval --kitti path/to/kitti    # scores toosicubix-out against KITTI ground truth
    """


main.add_command(schema.schema_command)
main.add_command(fit.fit_command)
main.add_command(validate.validate_command)
main.add_command(evaluate.eval_command)
main.add_command(simulate.simulate_command)
main.add_command(priors.priors_command)
main.add_command(tune.tune_command)
main.add_command(template.template_command)
main.add_command(import_tools.import_group)
main.add_command(export.export_group)
main.add_command(render.render_command)
main.add_command(annotate.annotate_command)
main.add_command(learn.learn_parts_command)

__all__ = ["EXIT_BAD_INPUT", "EXIT_OK", "EXIT_SOME_FAILED", "BadInput", "main"]

if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
