"""Commands that make data: ``generate`` (a benchmark stage), ``generate-run`` (a synthesised
recording) and ``figure stages``."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

from railwatch.cli.common import info, writable_file
from railwatch.errors import RailwatchError

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


@click.command(epilog=STAGE_TABLE)
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
    y, _, kind, _ = data.labels()
    info(f"wrote {out}: stage {stage_number}, X {data.X.shape}, {int(y.sum())} anomalous "
         f"({int((kind == 1).sum())} spikes), {time.perf_counter() - started:.1f} s")


@click.group()
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
    from railwatch.report.figures import save_figure, stages_figure
    from railwatch.synthetic import stage_examples

    writable_file(out)
    save_figure(stages_figure(stage_examples(seed), seed), out)
    info(f"wrote {out}")


def odometry_options(prefix: str) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """The options of repeated passes' positions and direction, shared by ``generate-run`` and
    ``simulate`` (``prefix`` opens each help text)."""
    options = [
        click.option("--odometry-offset", type=click.FloatRange(min=0), default=1.0,
                     show_default=True,
                     help=f"{prefix}std (m) of each pass's position offset error."),
        click.option("--odometry-drift", type=click.FloatRange(min=0), default=0.0005,
                     show_default=True, help=f"{prefix}std of each pass's relative scale error "
                                             "(0.0005: 0.5 m per km)."),
        click.option("--odometry-walk", type=click.FloatRange(min=0), default=0.3,
                     show_default=True,
                     help=f"{prefix}random walk of the position, m per square root of km."),
        click.option("--odometry-relative", is_flag=True,
                     help=f"{prefix}positions counted from each pass's start (an odometer "
                          "alone), not the track's (GNSS-aided)."),
        click.option("--push-pull", is_flag=True,
                     help=f"{prefix}the vehicle runs back without turning, so each side stays "
                          "on its rail (default: turned at the ends, a defect is felt on the "
                          "other side on the way back)."),
    ]

    def wrap(f: Callable[..., Any]) -> Callable[..., Any]:
        for option in reversed(options):
            f = option(f)
        return f

    return wrap


@click.command("generate-run")
@click.option("--minutes", type=float, default=10.0, show_default=True,
              help="Length of the run.")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--fs", type=float, default=2000.0, show_default=True, help="Sampling rate (Hz).")
@click.option("--defect-every", "every_s", type=float, default=10.0, show_default=True,
              help="Mean seconds between defects.")
@click.option("--stage", type=click.IntRange(5, 8), default=5, show_default=True,
              help="Benchmark stage carried into continuous time: 5 signals and changing noise, "
                   "6 + channel odds by defect kind, 7 + HF bursts at rough spots of the track, "
                   "8 + wheel-periodic impulses.")
@click.option("--loud-stretches", is_flag=True,
              help="Rough sections of track (200-1500 m, 4 in 10) with 2-4x the noise.")
@click.option("--passes", type=click.IntRange(min=1),
              help="Repeated passes over one track instead of one run: OUT is then a folder.")
@click.option("--track-km", type=click.FloatRange(min=0, min_open=True), default=10.0,
              show_default=True, help="With --passes: the track's length.")
@click.option("--track-defects", type=click.IntRange(min=0), default=40, show_default=True,
              help="With --passes: defects on the track, at fixed positions.")
@click.option("--format", "fmt", type=click.Choice(["parquet", "csv", "h5", "mat"]),
              default="parquet", show_default=True, help="With --passes: the recordings' format.")
@odometry_options("With --passes: ")
@click.option("--out", type=click.Path(path_type=Path), required=True,
              help="Recording file: .csv, .parquet, .h5 or .mat (the extension picks); with "
                   "--passes a folder.")
@click.pass_obj
def generate_run(obj: dict, minutes: float, seed: int, fs: float, every_s: float, stage: int,
                 loud_stretches: bool, passes: int | None, track_km: float, track_defects: int,
                 fmt: str, odometry_offset: float, odometry_drift: float, odometry_walk: float,
                 odometry_relative: bool, push_pull: bool, out: Path) -> None:
    """Synthesise a long six-channel run at the benchmark's scale with defects at known times
    and positions, or repeated passes over one track.

    \b
    The benchmark's scale: 2000 Hz, but defects twenty times longer than on a real rail (a
    10-ms spike, 0.05-0.2-s boxes), as the benchmark's windows scaled by the paper's x20; the
    layout says scale = "benchmark", and train prepares them as the paper does (100 Hz, 2-s
    windows). For field-scale recordings of real squats use 'railwatch simulate'.
    Writes OUT, OUT's layout (<name>.layout.toml) and the true defects (<name>.defects.csv).
    Stage-5 signals (axle, bogie, body groups) with a speed profile and changing noise; defects
    one every 10 s on average: spikes of +-3-4, local deviations of +-1.5-2 (0.05-0.2 s).
    --stage 7 and 8 add the later stages' nuisance, tied to the track and the wheels;
    --loud-stretches makes the noise level of whole sections of track change.
    With --passes N: one track with defects at fixed positions and N passes over it (each its
    own speed, noise, nuisance, start offset and odometry error; odd passes backwards, the
    vehicle turned round unless --push-pull), in
    OUT/: track.defects.csv (defects by position), layout.toml, passNN.<format> and
    passNN.defects.csv (when each pass crossed each defect).
    Examples:
      railwatch generate-run --minutes 10 --seed 1 --out train1.parquet
      railwatch generate-run --stage 8 --loud-stretches --seed 4 --out rough.parquet
      railwatch generate-run --passes 10 --track-km 10 --out runs/track/
    """
    if passes is not None:
        from railwatch.progress import Progress
        from railwatch.synthetic.track import Odometry, write_track

        if out.exists() and not out.is_dir():
            raise RailwatchError(f"--out {out} is a file: with --passes give a folder")
        started = time.perf_counter()
        with Progress(passes, "passes", "passes", enabled=obj["progress"], every_s=0.0) as bar:
            track, paths = write_track(
                out, passes, length_m=track_km * 1000, n_defects=track_defects, seed=seed,
                stage=stage, fs=fs, loud_stretches=loud_stretches,
                odometry=Odometry(odometry_offset, odometry_drift, odometry_walk,
                                  odometry_relative),
                suffix=f".{fmt}", push_pull=push_pull, progress=bar.update)
        info(f"wrote {passes} passes over {track_km:g} km with {len(track.defects)} defects "
             f"into {out} in {time.perf_counter() - started:.0f} s ({paths[0].name} ...)")
        return
    from railwatch.synthetic.run_files import check_run_settings, write_run

    check_run_settings(out, minutes, every_s, fs)
    writable_file(out)
    run, layout_path, truth_path = write_run(out, minutes, seed=seed, fs=fs, every_s=every_s,
                                             stage=stage, loud_stretches=loud_stretches)
    info(f"wrote {minutes:g} min at {fs:g} Hz with {len(run.defects)} defects: {out}, "
         f"{layout_path}, {truth_path}")


@click.command()
@click.option("--out", type=click.Path(path_type=Path, file_okay=False), required=True,
              help="Folder to write the track and its passes into.")
@click.option("--passes", type=click.IntRange(min=1), default=6, show_default=True,
              help="Passes over the track (odd ones run back).")
@click.option("--track-km", type=click.FloatRange(min=0.2), default=5.0, show_default=True,
              help="The track's length.")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Seed of the track (its items, irregularity, roughness, supports) and of "
                   "every pass; the same seed gives the same files.")
@click.option("--fs", type=float, default=2000.0, show_default=True,
              help="The recordings' rate (Hz), as a field logger's (1-5 kHz).")
@click.option("--speed", "speed_text", default="10-30", show_default=True,
              help="Speed range LOW-HIGH in m/s: each pass draws a new speed every 0.5-1.5 km "
                   "in it.")
@click.option("--irregularity", default="german-high", show_default=True,
              help="Long-wave irregularity spectrum: german-low, german-high, fra-1 ... fra-6, "
                   "or none.")
@click.option("--roughness", type=click.Choice(["average", "iso3095", "none"]),
              default="average", show_default=True,
              help="Short-wave rail roughness: an average network's, or the ISO 3095 limit "
                   "(freshly ground rail).")
@click.option("--wheel-flat", "flat_mm", type=click.FloatRange(min=0, max=3), default=0.0,
              show_default=True, help="Depth (mm) of a flat on the sensor wheelset's left "
                                      "wheel (0: none).")
@click.option("--format", "fmt", type=click.Choice(["parquet", "csv", "h5", "mat"]),
              default="parquet", show_default=True, help="The recordings' format.")
@click.option("--gnss", is_flag=True,
              help="Positions GNSS-aided: each pass 1 m off at its start (--odometry-offset), "
                   "0.01 % scale error, a walk of 0.1 m per square root of km, no error common "
                   "to the passes (the other odometry options do not apply).")
@click.option("--start", help="Date the passes: the first starts then (ISO 8601, e.g. "
                             "2026-01-05T06:00:00Z; no zone: UTC), each in a 'utc' column (s "
                             "since 1970) named by the layout's timestamp key.")
@click.option("--every-days", type=float, default=7.0, show_default=True,
              help="Days from one pass to the next (with --start).")
@click.option("--growing", type=click.FloatRange(0, 1), default=0.0, show_default=True,
              help="Share of the squats that grow: each deepens linearly in time to 1.2-3.0 "
                   "times its first depth at the last pass, and lengthens with it "
                   "(passNN.defects.csv: each pass's depth and length; track.defects.csv: the "
                   "first, and growth=).")
@odometry_options("")
@click.option("--odometry-common-offset", type=click.FloatRange(min=0), default=2.0,
              show_default=True, help="Std (m) of an offset every pass shares (the reference "
                                      "the odometer is set by).")
@click.option("--odometry-common-drift", type=click.FloatRange(min=0), default=0.001,
              show_default=True, help="Std of a scale error every pass shares (the wheel's "
                                      "worn radius: 0.001 is 1 m per km).")
@click.pass_obj
def simulate(obj: dict, out: Path, passes: int, track_km: float, seed: int, fs: float,
             speed_text: str, irregularity: str, roughness: str, flat_mm: float, fmt: str,
             gnss: bool, odometry_offset: float, odometry_drift: float, odometry_walk: float,
             odometry_relative: bool, push_pull: bool, odometry_common_offset: float,
             odometry_common_drift: float, start: str | None, every_days: float,
             growing: float) -> None:
    """Simulate a coach running over a track with real rail defects: field-rate recordings from
    a vehicle-track dynamics model, each with its clean twin.

    \b
    The physics (every parameter and its source: docs/physics.md):
      coach    the Manchester benchmark passenger coach: body, two bogies, four
               wheelsets, primary and secondary suspension (vertical and roll)
      track    UIC60 rail on pads, sleepers every 0.6 m, ballast, subgrade; irregularity
               from a standard spectrum, short-wave roughness, varying supports
      contact  Hertz, the wheel free to leave the rail and land again
      defects  squats (2-10 cm, 0.1-1.5 mm), dipped joints, welds, broken-rail steps,
               corrugation, each on one rail
      features turnouts (switch, crossing nose), bridge transitions, level crossings:
               they answer on every pass and are not defects
      sensors  axle boxes, bogie frame and car body, left and right, with noise,
               AC coupling and an anti-alias filter, at --fs
    \b
    Positions are an odometer's by default: each pass 1 m off at its start, its scale 0.05 %
    off, and every pass sharing a 2-m offset and a 0.1 % scale error (the same vehicle);
    --gnss makes them GNSS-aided.
    Writes into OUT: layout.toml, passNN.<format> (positions as recorded),
    passNN.defects.csv and passNN.features.csv (when each pass crossed each item),
    twins/passNN.<format> (the same pass without its defects, sensor noise and odometry
    error),
    track.defects.csv, track.features.csv, track.assets.csv (the features as an asset
    register for track-map --assets) and physics.json (every setting).
    --start dates the passes (a utc column, --every-days apart); --growing deepens a share
    of the squats from pass to pass (weeks to months of growth, for maps over time).
    A 5-km pass takes 10-20 s on 2 cores.
    Examples:
      railwatch simulate --out physics/
      railwatch simulate --out slow/ --passes 10 --speed 8-15 --gnss
      railwatch simulate --out weekly/ --passes 10 --start 2026-01-05T06:00Z --growing 0.5
    """
    from railwatch.physics.files import Positioning, Schedule, write_world
    from railwatch.physics.passes import PassPlan
    from railwatch.physics.world import World
    from railwatch.progress import Progress
    from railwatch.synthetic.track import Odometry

    if out.exists() and not out.is_dir():
        raise RailwatchError(f"--out {out} is a file: give a folder")
    low, sep, high = speed_text.partition("-")
    try:
        speed = (float(low), float(high if sep else low))
    except ValueError:
        raise RailwatchError(f"--speed {speed_text!r}: give LOW-HIGH in m/s, e.g. 10-30") \
            from None
    world = World(length_m=track_km * 1000.0,
                  irregularity=None if irregularity == "none" else irregularity,
                  roughness=None if roughness == "none" else roughness, flat_mm=flat_mm)
    plan = PassPlan(push_pull=push_pull, speed_ms=speed, fs=fs)
    positioning = Positioning(Odometry(odometry_offset, 0.0001, 0.1), 0.0, 0.0) if gnss else \
        Positioning(Odometry(odometry_offset, odometry_drift, odometry_walk, odometry_relative),
                    odometry_common_offset, odometry_common_drift)
    schedule = Schedule(start, every_days, growing)
    world.check()
    plan.check()
    schedule.check()
    started = time.perf_counter()
    with Progress(passes, "passes", "passes", enabled=obj["progress"], every_s=0.0) as bar:
        track, paths = write_world(
            out, passes, world, seed=seed, plan=plan, positioning=positioning,
            suffix=f".{fmt}", progress=bar.update, schedule=schedule)
    kinds = ", ".join(f"{sum(d.kind == k for d in track.defects)} {k}s"
                      for k in sorted({d.kind for d in track.defects}))
    info(f"wrote {passes} passes over {track_km:g} km ({kinds}; {len(track.features)} features) "
         f"into {out} in {time.perf_counter() - started:.0f} s ({paths[0].name} ...)")

