"""The map on the earth: GeoJSON (RFC 7946, checked against a schema written from it, and read
by GDAL through pyogrio) and KML, with GNSS fixes and without; one-line errors."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import jsonschema
import numpy as np
import pytest

from railwatch.cli import main
from railwatch.physics import gnss
from support import scan_folder

DEFECTS = np.array([700.0, 1900.0, 3100.0])
POSITION = {"type": "array", "minItems": 2, "maxItems": 3,
            "prefixItems": [{"type": "number", "minimum": -180, "maximum": 180},
                            {"type": "number", "minimum": -90, "maximum": 90}]}
#: RFC 7946 for what railwatch writes: a FeatureCollection of Features whose geometry is a
#: Point, a LineString or null, positions longitude then latitude, properties an object.
SCHEMA = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "type": "object", "required": ["type", "features"],
    "properties": {
        "type": {"const": "FeatureCollection"},
        "features": {"type": "array", "items": {
            "type": "object", "required": ["type", "properties", "geometry"],
            "properties": {
                "type": {"const": "Feature"},
                "properties": {"type": ["object", "null"]},
                "geometry": {"oneOf": [
                    {"type": "null"},
                    {"type": "object", "required": ["type", "coordinates"], "properties": {
                        "type": {"const": "Point"}, "coordinates": POSITION}},
                    {"type": "object", "required": ["type", "coordinates"], "properties": {
                        "type": {"const": "LineString"},
                        "coordinates": {"type": "array", "minItems": 2, "items": POSITION}}}]}}}},
    }}


def folder(tmp: Path, located: bool) -> Path:
    rng = np.random.default_rng(1)
    xs, scores = [], []
    for _ in range(5):
        x = np.arange(0, 4_000.0, 0.25) + rng.uniform(0, 0.25)
        s = rng.exponential(size=len(x))
        for d in DEFECTS:
            s[np.abs(x - d) <= 0.4] += 12.0
        xs.append(x)
        scores.append(s)
    tmp.mkdir()
    scan_folder(tmp, xs, scores, DEFECTS, located=located)
    return tmp


def places(collection: dict) -> list[dict]:  # type: ignore[type-arg]
    return [f for f in collection["features"] if f["properties"]["kind"] == "place"]


def mapped(tmp: Path, located: bool) -> tuple[Path, Path, dict]:  # type: ignore[type-arg]
    """The scan folder, the GeoJSON of its map and the GeoJSON read (schema-checked)."""
    scans = folder(tmp / "scan", located=located)
    out = tmp / "m.geojson"
    assert main(["track-map", "--events", str(scans), "--out", str(tmp / "m.csv"),
                 "--geojson", str(out)]) == 0
    collection = json.loads(out.read_text())
    jsonschema.validate(collection, SCHEMA)
    return scans, out, collection


def test_with_gnss_places_lie_where_the_defects_are(tmp_path: Path) -> None:
    scans, out, collection = mapped(tmp_path, located=True)
    found = places(collection)
    assert len(found) == 3 and [f["properties"]["priority"] for f in found] == [1, 2, 3]
    s, east, north = gnss.line(-500.0, 20_000.0, 0)
    for f in found:
        lon, lat = f["geometry"]["coordinates"]
        km = f["properties"]["track_km"]
        want_lat, want_lon = gnss.to_degrees(np.interp(km * 1e3, s, east),
                                             np.interp(km * 1e3, s, north))
        off_m = np.hypot((lat - want_lat) * np.pi / 180 * gnss.EARTH_RADIUS_M,
                         (lon - want_lon) * np.pi / 180 * gnss.EARTH_RADIUS_M * 0.63)
        assert off_m < 0.5, off_m
        assert min(abs(km * 1e3 - DEFECTS)) < 2
    line = [f for f in collection["features"] if f["properties"]["kind"] == "line"]
    assert len(line) == 1 and len(line[0]["geometry"]["coordinates"]) > 350
    pyogrio = pytest.importorskip("pyogrio")
    meta, _, geometry, _ = pyogrio.raw.read(out)  # GDAL's GeoJSON driver
    assert len(geometry) == 4 and "priority" in list(meta["fields"])
    # KML: the line and the three places, each a Placemark with a Point.
    kml = tmp_path / "m.kml"
    assert main(["track-map", "--events", str(scans), "--out", str(tmp_path / "m.csv"),
                 "--geojson", str(kml)]) == 0
    ns = {"k": "http://www.opengis.net/kml/2.2"}
    root = ET.parse(kml).getroot()
    assert len(root.findall(".//k:Placemark", ns)) == 4
    assert len(root.findall(".//k:Point", ns)) == 3


def test_without_gnss_places_keep_their_track_km(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    scans, out, collection = mapped(tmp_path, located=False)
    found = places(collection)
    assert len(found) == 3 and all(f["geometry"] is None for f in found)
    assert sorted(round(f["properties"]["track_km"], 1) for f in found) == [0.7, 1.9, 3.1]
    assert not [f for f in collection["features"] if f["properties"]["kind"] == "line"]
    pyogrio = pytest.importorskip("pyogrio")
    _, _, _, fields = pyogrio.raw.read(out)
    assert len(fields[0]) == 3
    capsys.readouterr()
    for name, said in (("m.kml", "KML needs positions on the earth"),
                       ("m.shp", "write .geojson (or .json), or .kml")):
        assert main(["track-map", "--events", str(scans), "--out", str(tmp_path / "m.csv"),
                     "--geojson", str(tmp_path / name)]) != 0
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and said in err, err
        assert not (tmp_path / name).exists()


def test_the_schema_can_fail() -> None:
    """The schema refuses what RFC 7946 refuses: latitude first, a bare geometry list."""
    bad = {"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {}, "geometry": {"type": "Point",
                                                            "coordinates": [51.0, 190.0]}}]}
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(bad, SCHEMA)
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({"type": "FeatureCollection", "features": [{"type": "Point"}]},
                            SCHEMA)
