"""The ``railwatch`` command line. Thin: it parses arguments, calls the library, and is the only
place that talks to the terminal. Every failure ends in one line on stderr and a non-zero exit.

One module per command group: :mod:`~railwatch.cli.data` (generate, generate-run, figure),
:mod:`~railwatch.cli.models` (detectors, train, score, evaluate, export),
:mod:`~railwatch.cli.recordings` (detect), :mod:`~railwatch.cli.tracks` (scan, track-map) and
:mod:`~railwatch.cli.bench` (bench).
"""

from __future__ import annotations

import logging
import os
import sys

import click

from railwatch import __version__
from railwatch.cli import bench, data, models, recordings, tracks
from railwatch.errors import RailwatchError, one_line

log = logging.getLogger("railwatch")


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, prog_name="railwatch")
@click.option("-q", "--quiet", is_flag=True, help="No progress bars or log lines.")
@click.pass_context
def cli(ctx: click.Context, quiet: bool) -> None:
    """railwatch: find small transient rail defects in onboard accelerometer data, unsupervised.

    \b
    Generate the 8-stage synthetic benchmark, draw its example figure:
      railwatch generate --stage 7 --n 3000 --seed 0 --out stage7.npz
      railwatch figure stages --out stages.png
    Train a detector without labels, score and evaluate:
      railwatch detectors
      railwatch train --detector aft-attention --data train.npz --out model/
      railwatch score --model model/ --data test.npz --out scores.npz
      railwatch evaluate --data test.npz --scores scores.npz
    Simulate a coach over a track with real squats, joints and welds (2 kHz recordings):
      railwatch simulate --out physics/

    Run any command with --help for its options.
    """
    ctx.obj = {"progress": not quiet}
    logging.basicConfig(level=logging.WARNING if quiet else logging.INFO,
                        format="%(message)s", stream=sys.stderr)


for command in (data.generate, data.generate_run, data.simulate, data.figure,
                models.list_detectors, models.train, models.score, models.evaluate,
                models.export, recordings.detect, tracks.scan, tracks.track_map, bench.bench):
    cli.add_command(command)


def main(argv: list[str] | None = None) -> int:
    """Entry point: run the CLI, turning every error into one line and an exit code."""
    try:
        rv = cli.main(args=argv, prog_name="railwatch", standalone_mode=False)
        return rv if isinstance(rv, int) else 0
    except click.exceptions.NoArgsIsHelpError as e:
        click.echo(e.ctx.get_help() if e.ctx else str(e))
        return 0
    except click.UsageError as e:
        where = f" (see '{e.ctx.command_path} --help')" if e.ctx else ""
        click.echo(f"railwatch: error: {e.format_message()}{where}", err=True)
        return 2
    except click.ClickException as e:
        click.echo(f"railwatch: error: {e.format_message()}", err=True)
        return e.exit_code
    except click.exceptions.Abort:
        click.echo("railwatch: aborted", err=True)
        return 130
    except (RailwatchError, ValueError, OSError) as e:
        if os.environ.get("RAILWATCH_DEBUG"):
            raise
        click.echo(f"railwatch: error: {one_line(e)}", err=True)
        return 1
    except Exception as e:  # noqa: BLE001 - the user gets one line, the debug flag the traceback
        if os.environ.get("RAILWATCH_DEBUG"):
            raise
        click.echo(f"railwatch: internal error: {type(e).__name__}: {one_line(e)} "
                   "(set RAILWATCH_DEBUG=1 for the traceback and please report it)", err=True)
        return 1
