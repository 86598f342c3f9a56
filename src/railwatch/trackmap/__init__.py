"""The repeated-pass workflow: many recordings of one line scanned by a model, then fused into
a map of places to inspect.

=========================================  ==================================================
:mod:`~railwatch.trackmap.scan`            ``railwatch scan``: one model over many recordings
                                           (locally or as Ray tasks, resumable)
:mod:`~railwatch.trackmap.folder`          the scan folder it writes and the map reads (every
                                           file name and key), and the map's CSV
:mod:`~railwatch.trackmap.align`           the passes' odometry laid on each other
:mod:`~railwatch.trackmap.fusion`          evidence fused across passes, and its calibration
:mod:`~railwatch.trackmap.maps`            the map: fused (default) or votes, and what it
                                           reports
:mod:`~railwatch.trackmap.assets`          the asset register: places labelled by the assets
                                           they lie on, assets measured against their kind
:mod:`~railwatch.trackmap.learned`         a register learned from the passes: places that
                                           look like assets, proposed
:mod:`~railwatch.trackmap.trends`          a place's strength over dated passes, and whether
                                           it grows faster than chance
:mod:`~railwatch.trackmap.worklist`        the places to inspect, most urgent first
:mod:`~railwatch.trackmap.geo`             the places on the earth (GNSS), as GeoJSON or KML
=========================================  ==================================================

Scoring a map against the true defects is evaluation: :mod:`railwatch.evaluation.maps`. How the
map works and its choices: ``docs/track-map.md``.
"""

from railwatch.trackmap import assets, fusion, geo, learned, maps, trends, worklist
from railwatch.trackmap.align import (
    align,
    chance_gain,
    fit_transform,
    refine_by_profiles,
    verify_moves,
)
from railwatch.trackmap.folder import (
    COMBINED,
    EVENTS_SUFFIX,
    MAP_FIELDS,
    PROFILE_KIND,
    PROFILE_SUFFIX,
    SCAN_SUFFIX,
    Location,
    PassEvents,
    ScoreProfile,
    read_scan,
    write_map,
)
from railwatch.trackmap.maps import (
    MIN_EVENTS,
    SIDES,
    covered_range,
    fused_map,
    min_events_for,
    rail_scores,
    reported,
    reported_fused,
    single_linkage,
    track_map,
    wilson_lower,
)

__all__ = ["assets", "fusion", "geo", "learned", "maps", "trends", "worklist", "COMBINED",
           "EVENTS_SUFFIX", "MAP_FIELDS", "MIN_EVENTS", "PROFILE_KIND", "PROFILE_SUFFIX",
           "SCAN_SUFFIX", "SIDES",
           "Location", "PassEvents", "ScoreProfile", "align", "chance_gain", "covered_range",
           "fit_transform", "fused_map", "min_events_for", "rail_scores", "read_scan",
           "refine_by_profiles", "reported", "reported_fused", "single_linkage", "track_map",
           "verify_moves", "wilson_lower", "write_map"]
