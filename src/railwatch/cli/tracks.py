"""Commands from recordings to a track map: ``scan`` (many recordings, one model, locally or
on Ray) and ``track-map`` (events of repeated passes -> confirmed locations)."""

from __future__ import annotations

import glob
from pathlib import Path

import click

from railwatch.cli.common import info, writable_file
from railwatch.errors import RailwatchError

#: How track-map ranks places: fused_map (evidence from every pass's scores) or track_map (the
#: share of passes with an event), both in railwatch.trackmap.maps.
METHOD_CHOICES = ("fused", "votes")
#: railwatch.trackmap.SIDES (not imported here: the CLI loads the track map lazily).
SIDES_CHOICES = ("auto", "swap", "keep", "group")


def expand_recordings(items: tuple[str, ...]) -> list[Path]:
    """Files, folders (every recording in them) and shell globs, in name order."""
    from railwatch.recordings.readers import FORMATS

    found: list[Path] = []
    for item in items:
        path = Path(item)
        if path.is_dir():
            found += sorted(p for p in path.iterdir() if p.suffix.lower() in FORMATS)
        elif any(ch in item for ch in "*?["):
            matches = sorted(Path(p) for p in glob.glob(item))
            if not matches:
                raise RailwatchError(f"no recording matches {item}")
            found += matches
        else:
            found.append(path)
    return found


@click.command(epilog="""\b
OUT gets, per recording NAME: NAME.events.csv, NAME.profile.npz (every sample's score per
channel from the window it is most central in, and its position: what track-map fuses across
passes) and NAME.scan.json (what was scanned, the stretch of track covered); and events.csv,
every event with its recording. A recording scanned before by the same model (same file, same
threshold) is not scanned again: kill a scan and start it again, and it goes on where it
stopped.
\b
Dates: a recording is dated by the layout's timestamp column (its first sample: a date-time,
or seconds since 1970-01-01 UTC) or by --dates, a CSV with the columns recording (file name)
and started (ISO 8601, e.g. 2026-03-01T08:15:00Z), which wins. track-map orders the passes by
date and selects them with --since and --until; a recording without a date is still scanned.
\b
GNSS: where the layout names latitude and longitude columns (degrees), NAME.profile.npz also
keeps the recording's route, its fixes at 10 Hz: track-map --geojson and --report then put the
places on the earth.""")
@click.option("--model", type=click.Path(path_type=Path), required=True,
              help="Model folder written by 'railwatch train --recordings' (or its .onnx).")
@click.option("--recordings", "recordings", multiple=True, required=True, metavar="PATH...",
              help="Recordings: files, folders or globs (quote globs for Ray on a cluster).")
@click.argument("more_recordings", nargs=-1)
@click.option("--out", type=click.Path(path_type=Path, file_okay=False), required=True,
              help="Scan folder (created; finished recordings in it are kept).")
@click.option("--layout", "layout_file", type=click.Path(path_type=Path),
              help="Layout of these recordings if their columns differ from the training layout.")
@click.option("--threshold", type=float,
              help="Event threshold instead of the model's (lower finds more; a map of "
                   "repeated passes filters what does not repeat).")
@click.option("--executor", type=click.Choice(["local", "ray"]), default="local",
              show_default=True, help="Scan in this process, or each recording as a Ray task.")
@click.option("--address", help="Ray cluster address (with --executor ray); default: start a "
                                 "local Ray on this machine.")
@click.option("--dates", "dates_file", type=click.Path(path_type=Path), metavar="DATES.csv",
              help="When each recording began (CSV: recording, started), if the recordings "
                   "carry no timestamp column (below).")
def scan(model: Path, recordings: tuple[str, ...], more_recordings: tuple[str, ...], out: Path,
         layout_file: Path | None, threshold: float | None, executor: str,
         address: str | None, dates_file: Path | None) -> None:
    """Scan many recordings for defects with one model: events per recording and combined.

    \b
    Example:
      railwatch scan --model model/ --recordings runs/track/pass*.parquet --out scan/
      railwatch scan --model model/ --recordings runs/ --out scan/ --executor ray
    """
    from railwatch.progress import Progress
    from railwatch.recordings.layout import load_layout
    from railwatch.trackmap.scan import read_dates
    from railwatch.trackmap.scan import scan as scan_recordings

    if address and executor != "ray":
        raise RailwatchError("--address goes with --executor ray")
    paths = expand_recordings(recordings + more_recordings)
    layout = load_layout(layout_file) if layout_file else None
    dates = read_dates(dates_file) if dates_file else None
    ctx = click.get_current_context()
    bar = Progress(len(paths), "scan", "recordings", every_s=0.0,
                   enabled=(ctx.find_root().obj or {}).get("progress", True))

    def done(name: str, events: int | None) -> None:
        if events is not None:
            bar.set_postfix_str(f"{name}: {events} events")
        bar.update(1, timed=events is not None)

    with bar:
        summary = scan_recordings(model, paths, out, layout=layout, threshold=threshold,
                                  executor=executor, address=address, on_recording=done,
                                  dates=dates)
    rate = summary.recording_s / 3600 / max(summary.wall_s / 3600, 1e-9)
    info(f"{len(paths)} recordings ({summary.reused} scanned before), {summary.events} events; "
         f"{summary.wall_s:.1f} s" + (f", {rate:.0f} recording-hours per hour"
                                      if summary.scanned == len(paths) else "")
         + f"; wrote {out / 'events.csv'}")


@click.command("track-map", epilog="""\b
MAP.csv: one row per place (fused: every place that chance gives at most once per km, the
reported ones and those just below), most evident first: rank, position_m (the map's frame: the
median of the passes' odometry), start_m, end_m, evidence (-log10 of the fused tail),
false_per_km (how many places this strong passes without a repeating defect give per km: the
map's own false-alarm estimate), passes_seen (passes whose score there, measured against its
neighbourhood, is in the top 1 % of the pass), passes_with_event, passes_covered, share,
confidence (95 % lower bound of the share), median_score, channel (the rail, named by the
channel over it on a pass up the map; with --sides group the channel most passes had highest
there), group, kind_guess (spike-like or deviation-like, from the events' duration),
first_seen, last_seen (recording names; the passes in the order they were recorded where scan
dated them), asset, asset_kind (with --assets: the asset the place lies on, or "unexplained":
a candidate defect), growth, growth_low, growth_high, trend_p, growing (over 4 dated passes
or more: the place's strength at the last pass over the first's, fitted with each pass's level
and the place's speed taken out, its 95 % interval, and "yes" where a stable place gives a
slope this steep less than 2.5 % of the time). MAP.passes.csv: each place's strength per pass.
MAP.worklist.csv: where to send an inspector, most urgent first: growing unexplained places,
then unexplained places, then assets that grow or answer more than their kind; each with why.
\b
--assets ASSETS.csv: the asset register, one row per asset: kind (switch, crossing, insulated
joint, weld, bridge transition, level crossing or your own), position_m (and length_m) or
start_m and end_m, id (optional). It also writes MAP.assets.csv: every asset on the line with
its response (the median over the passes of its highest score) and kind_z (how far above the
other assets of its kind, in their spread); abnormal = yes from 3.5, given 4 of the kind.
\b
--method votes ranks the places where events cluster by the share of passes with an event
(evidence and false_per_km empty); it needs only the events.""")
@click.option("--events", "events_dir", type=click.Path(path_type=Path), required=True,
              help="Scan folder written by 'railwatch scan' (events, score profiles, the track "
                   "covered).")
@click.option("--out", type=click.Path(path_type=Path, dir_okay=False), required=True,
              help="Map to write (.csv).")
@click.option("--plot", type=click.Path(path_type=Path, dir_okay=False),
              help="Also draw the track with the evidence and the reported places (PNG).")
@click.option("--report", "report_out", type=click.Path(path_type=Path, dir_okay=False),
              metavar="MAP.html",
              help="Also write the map as one HTML page that works offline: the line, the "
                   "places by status, each place's strength per pass, the work list.")
@click.option("--geojson", "geojson_out", type=click.Path(path_type=Path, dir_okay=False),
              metavar="FILE",
              help="Also write the reported places (and the line) for a GIS: .geojson, or .kml "
                   "(needs GNSS fixes). With GNSS in the recordings, latitude and longitude; "
                   "otherwise track km, no geometry.")
@click.option("--method", type=click.Choice(METHOD_CHOICES), default="fused", show_default=True,
              help="fused: every pass's scores, calibrated and summed per place; votes: count "
                   "the passes with an event.")
@click.option("--false-per-km", type=click.FloatRange(min=0, min_open=True), default=0.1,
              show_default=True,
              help="fused: report places stronger than chance gives this often per km.")
@click.option("--tolerance-m", type=click.FloatRange(min=0, min_open=True), default=2.0,
              show_default=True, help="Events of different passes closer than this are one place.")
@click.option("--max-offset-m", type=click.FloatRange(min=0), default=50.0, show_default=True,
              help="Largest offset between two passes' positions (track positions: no pass "
                   "is turned round); 0: any (positions counted from each pass's start, "
                   "either way along the track).")
@click.option("--sides", type=click.Choice(SIDES_CHOICES), default="auto", show_default=True,
              help="fused: how each pass's channels are laid on the rails. swap: a vehicle "
                   "turned at the line's ends (a sensor group's channels, its sides, swap rails "
                   "with the direction); keep: push-pull (they stay); group: each group's "
                   "highest channel (either); auto: swap or keep, the one under which the "
                   "passes agree most.")
@click.option("--min-events", default="auto", show_default=True, metavar="N|auto",
              help="fused: report a place only where at least N passes had an event. auto: 1 "
                   "when the scanning model was trained at field scale (a rail's own texture "
                   "agrees across passes below the event threshold), 0 at the benchmark's.")
@click.option("--min-share", type=click.FloatRange(0, 1), default=0.3, show_default=True,
              help="votes: report a place seen on at least this share of the passes that "
                   "covered it, and on 2 passes at least (one pass confirms nothing).")
@click.option("--assets", "assets_file", type=click.Path(path_type=Path),
              help="Asset register (CSV, see below): label every place with the asset it lies "
                   "on or 'unexplained', and write MAP.assets.csv.")
@click.option("--learn-assets", is_flag=True,
              help="No register: propose as assets the places seen on nearly every pass, "
                   "stable, on both rails alike (switches, bridge transitions, level "
                   "crossings), and a turnout's crossing nose: the nearest such place on one "
                   "rail within 60 m of a switch, at least as strong; they are labelled so, and "
                   "MAP.learned-assets.csv is a register to confirm and give back with "
                   "--assets.")
@click.option("--asset-tolerance-m", type=click.FloatRange(min=0), default=5.0,
              show_default=True,
              help="A place lies on an asset within this distance of its stretch (the map's "
                   "positions carry the passes' common odometry error: 1-3 m).")
@click.option("--since", metavar="DATE",
              help="Map only the passes recorded on or after this date (ISO 8601: 2026-03-01, "
                   "or 2026-03-01T08:15); undated passes are left out.")
@click.option("--until", metavar="DATE",
              help="... and on or before this date (a date alone: to its end).")
@click.option("--truth", type=click.Path(path_type=Path),
              help="True defects by position (a position_m column, and length_m if they are "
                   "long, e.g. the track.defects.csv of 'generate-run --passes'): recall and "
                   "false locations per km.")
def track_map(events_dir: Path, out: Path, plot: Path | None, report_out: Path | None,
              geojson_out: Path | None, method: str, false_per_km: float,
              tolerance_m: float, max_offset_m: float, sides: str, min_events: str,
              min_share: float, assets_file: Path | None, learn_assets: bool,
              asset_tolerance_m: float,
              since: str | None, until: str | None, truth: Path | None) -> None:
    """Turn repeated passes over one line into ranked places on the track.

    \b
    Passes are aligned (each pass's odometry offset and drift, from the events that repeat,
    refined by the score profiles); each pass's scores are scaled by its own neighbourhood,
    ranked within the pass and summed over the passes at every place: a defect raises the
    score on most passes, even below the event threshold; a false event or a loud stretch of
    one pass does not repeat. What counts as evident is measured by shifting the passes
    against each other at random.
    Examples:
      railwatch track-map --events scan/ --out map.csv --plot map.png --truth track.defects.csv
      railwatch track-map --events scan/ --out map.csv --assets register.csv --report map.html
    """
    from railwatch import trackmap as tm
    from railwatch.evaluation import maps as em

    if out.suffix.lower() != ".csv":
        raise RailwatchError(f"--out {out.name}: write the map to a .csv file")
    writable_file(out)
    for extra in (plot, report_out, geojson_out):
        if extra is not None:
            writable_file(extra)
    if report_out is not None and report_out.suffix.lower() not in (".html", ".htm"):
        raise RailwatchError(f"--report {report_out.name}: write the report to a .html file")
    passes, left = tm.maps.by_date(tm.read_scan(events_dir), since, until)
    if not passes:
        raise RailwatchError(f"no pass of {events_dir} was recorded between --since and --until "
                             f"({len(left)} left out, "
                             f"{sum(not p.started for p in left)} of them undated)")
    truth_m = em.read_truth(truth) if truth else None  # read before the work: fail early
    if geojson_out is not None:
        tm.geo.check_out(geojson_out, passes)
    if assets_file and learn_assets:
        raise RailwatchError("give --assets (a register) or --learn-assets (one learned from "
                             "the passes), not both")
    if learn_assets and (method == "votes" or sides == "group"):
        raise RailwatchError("--learn-assets needs the fused map with the rails told apart: "
                             "--method fused and --sides swap, keep or auto")
    register = tm.assets.read_assets(assets_file) if assets_file else None
    beside = tm.worklist.outputs(out)
    for key, wanted in (("assets", register is not None or learn_assets),
                        ("passes", any(p.started for p in passes)), ("worklist", True),
                        ("learned-assets", learn_assets)):
        if wanted:
            writable_file(beside[key])
    made = tm.maps.make_map(passes, method, tolerance_m, max_offset_m, sides, min_events,
                            false_per_km, min_share)
    done = tm.worklist.plan(made, passes, register, asset_tolerance_m,
                            tolerance_m + tm.fusion.SLACK_M, tm.covered_range(passes),
                            learn_assets)
    written = tm.worklist.write_plan(out, made, done)
    if plot is not None:
        from railwatch.report.figures import save_figure, track_map_figure

        save_figure(track_map_figure(made.places, passes, made.reported, truth_m, made.fused,
                                     made.level, done.labelled.on_line if done.labelled else ()),
                    plot)
    when = tm.maps.dates_said(passes, left)
    line = (f"{len(passes)} passes{f' ({when})' if when else ''}, "
            f"{sum(len(p.position) for p in passes)} events -> "
            f"{len(made.places)} places, {len(made.reported)} reported ({made.rule})")
    if done.proposed is not None:
        line += f"; {len(done.proposed)} assets learned from the passes"
    if done.labelled is not None:
        line += "; " + tm.assets.summary(done.labelled, made.reported,
                                         register or tm.learned.register(done.proposed or []))
    if truth is not None and truth_m is not None:
        line += "; " + em.against_truth(made.reported, truth_m, truth,
                                        *tm.covered_range(passes), tolerance_m)
    line += "; " + tm.worklist.growing_said(made, done)
    if geojson_out is not None or report_out is not None:
        geo = tm.geo.locate(made, passes, tm.covered_range(passes))
        if geojson_out is not None:
            written.append(tm.geo.write(geojson_out, made, done, geo))
        if report_out is not None:
            from railwatch.report.map_report import report_map

            written.append(report_map(report_out, made, done, passes, geo, line,
                                      tolerance_m + tm.fusion.SLACK_M))
    info(line + f"; wrote {', '.join(map(str, written))}" + (f" and {plot}" if plot else ""))
