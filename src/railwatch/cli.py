"""The ``railwatch`` command line. Thin: it parses arguments, calls the library, and is the only
place that talks to the terminal. Every failure ends in one line on stderr and a non-zero exit.
"""

from __future__ import annotations

import logging
import os
import sys
import time
from pathlib import Path

import click

from railwatch import __version__
from railwatch.errors import RailwatchError

log = logging.getLogger("railwatch")

STAGE_TABLE = """\b
  stage  channels  adds
  1      1         sinusoid + white noise (3 random variables)
  2      1         phase-continuous speed change at t_change (6)
  3      2         two channels, phase offsets (14)
  4      2         noise std steps up at t_noisechange (18)
  5      6         axle / bogie / body groups with their own ranges (54)
  6      6         anomalous channel drawn from kind-specific odds (54)
  7      6         one high-frequency burst on every channel (84)
  8      6         periodic truncated-Gaussian impulses (102)"""


def writable_file(path: Path) -> Path:
    """Fail early, in one line, if ``path`` cannot be written (before any long work)."""
    parent = path.parent if str(path.parent) else Path(".")
    if path.is_dir():
        raise RailwatchError(f"{path} is a directory: give a file name, e.g. {path}/out.npz")
    if not parent.is_dir():
        raise RailwatchError(
            f"cannot write {path}: folder {parent} does not exist (create it first)")
    if not os.access(parent, os.W_OK):
        raise RailwatchError(f"cannot write {path}: folder {parent} is not writable")
    return path


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

    Run any command with --help for its options.
    """
    ctx.obj = {"progress": not quiet}
    logging.basicConfig(level=logging.WARNING if quiet else logging.INFO,
                        format="%(message)s", stream=sys.stderr)


@cli.command(epilog=STAGE_TABLE)
@click.option("--stage", "stage_number", type=click.IntRange(1, 8), required=True,
              help="Benchmark stage, 1-8 (table below).")
@click.option("--n", type=click.IntRange(min=1), default=1000, show_default=True,
              help="Number of windows. Exactly round(0.1 n) are anomalous, half of them spikes.")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Seed; the same seed, stage and n give bit-identical output.")
@click.option("--out", type=click.Path(path_type=Path, dir_okay=False), required=True,
              help="Output .npz file (written atomically; loads with plain numpy.load).")
@click.option("--components", is_flag=True,
              help="Also store the nuisance signal and per-sample noise std (for the oracle).")
@click.option("--fs", type=click.FloatRange(min=0, min_open=True), default=100.0,
              show_default=True,
              help="Sampling rate in Hz. 2000 gives field-rate data: the same signals 20x finer.")
@click.option("--duration", type=click.FloatRange(min=0.2), default=2.0, show_default=True,
              help="Window length in seconds.")
@click.option("--bernoulli", is_flag=True,
              help="Draw each window anomalous with probability 0.1 instead of exactly 10 %.")
@click.pass_obj
def generate(obj: dict, stage_number: int, n: int, seed: int, out: Path, components: bool,
             fs: float, duration: float, bernoulli: bool) -> None:
    """Generate one labelled set of a benchmark stage into an .npz file.

    \b
    The file holds X (n, T, C) float32 windows, y (n,) instance labels, mask (n, T, C) true where
    an anomaly was added, kind (n,) 0 normal / 1 spike / 2 local deviation, channel (n,) the
    anomalous channel or -1, every sampled parameter as param_<name>, and meta, a JSON string
    (stage, seed, fs, channel names and groups, spec version, parameter keys).
    """
    from railwatch.synthetic import generate as generate_set

    writable_file(out)
    started = time.perf_counter()
    data = generate_set(stage_number, n, seed, fs=fs, duration=duration,
                        exact_rate=not bernoulli, components=components,
                        progress=obj["progress"])
    data.save(out)
    log.info("wrote %s: stage %d, X %s, %d anomalous (%d spikes), %.1f s",
             out, stage_number, data.X.shape, int(data.y.sum()), int((data.kind == 1).sum()),
             time.perf_counter() - started)


@cli.group()
def figure() -> None:
    """Draw figures (PNG)."""


@figure.command("stages")
@click.option("--out", type=click.Path(path_type=Path, dir_okay=False), required=True,
              help="Output PNG file.")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Seed of the example windows.")
def figure_stages(out: Path, seed: int) -> None:
    """The paper's Figure 1: one anomalous window of each of the 8 stages.

    The anomaly is red, speed changes dashed green, noise steps dotted purple, HF bursts shaded
    orange, impulse onsets triangles; each title gives the number of random variables.
    """
    from railwatch.evaluation.figures import save_figure, stages_figure

    writable_file(out)
    save_figure(stages_figure(seed), out)
    log.info("wrote %s", out)


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
        click.echo(f"railwatch: error: {_one_line(e)}", err=True)
        return 1
    except Exception as e:  # noqa: BLE001 - the user gets one line, the debug flag the traceback
        if os.environ.get("RAILWATCH_DEBUG"):
            raise
        click.echo(f"railwatch: internal error: {type(e).__name__}: {_one_line(e)} "
                   "(set RAILWATCH_DEBUG=1 for the traceback and please report it)", err=True)
        return 1


def _one_line(e: BaseException) -> str:
    return " ".join(str(e).split()) or type(e).__name__


if __name__ == "__main__":
    sys.exit(main())
