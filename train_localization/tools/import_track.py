"""Import a track network from OpenStreetMap or railML 3 into the project's network YAML.

  python -m train_localization.tools.import_track FILE -o OUT.yaml [--anchor LAT,LON] [--id NAME]

FILE: an OSM extract (.osm, .osm.pbf, .osm.bz2; osmium) or a railML 3 file (.xml, .railml; lxml),
told apart by its name or, failing that, its root element. The output is a network YAML
(docs/network.md) with its ``geodetic`` anchor (``--anchor``, else the middle of the data),
loadable as a scenario's ``track``. What the importer leaves out (or reads otherwise than tagged) is printed on stderr, one line
each, and listed in the file's header. Exit code 0, or 2 with one line when the file makes no
network.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import yaml

from ..core.geodesy import GeodesyError, GeodeticAnchor
from ..core.network.importing.build import Imported, TrackImportError
from ..core.network.importing.osm import read_osm
from ..core.network.importing.railml import read_railml

OSM_SUFFIXES = (".osm", ".pbf", ".o5m", ".opl", ".bz2", ".gz")


def is_osm(path: Path) -> bool:
    """An OSM file by its suffixes, else by its first XML element."""
    if path.suffix in OSM_SUFFIXES:
        return True
    with open(path, "rb") as fh:
        return b"<osm" in fh.read(4096)


def import_file(path: str | Path, anchor: GeodeticAnchor | None = None, network_id: str | None = None) -> Imported:
    """The network of an OSM or railML file; TrackImportError in one line."""
    path = Path(path)
    if not path.is_file():
        raise TrackImportError(f"{path}: no such file")
    reader = read_osm if is_osm(path) else read_railml
    return reader(path, anchor, network_id)


def to_yaml(imported: Imported, source: str) -> str:
    s = imported.data["sections"]
    header = [f"# Imported from {source} (python -m train_localization.tools.import_track): "
              f"{len(s)} sections, {len(imported.data['nodes'])} nodes."]
    header += [f"# note: {note}" for note in imported.notes]
    return "\n".join(header) + "\n" + yaml.safe_dump(imported.data, sort_keys=False, default_flow_style=None,
                                                     width=110)


def _anchor(text: str) -> GeodeticAnchor:
    try:
        lat, lon = (float(v) for v in text.split(","))
        return GeodeticAnchor(lat, lon)
    except (ValueError, GeodesyError) as exc:
        raise argparse.ArgumentTypeError(f"--anchor LAT,LON in degrees: {exc}") from None


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("file", type=Path)
    ap.add_argument("-o", "--out", type=Path, required=True, help="network YAML to write")
    ap.add_argument("--anchor", type=_anchor, help="LAT,LON [deg] of the map origin (default: the data's middle)")
    ap.add_argument("--id", help="network_id (default: the file's name)")
    args = ap.parse_args(argv)
    try:
        imported = import_file(args.file, args.anchor, args.id)
    except TrackImportError as exc:
        print(f"import_track: {exc}", file=sys.stderr)
        return 2
    for note in imported.notes:
        print(f"import_track: {note}", file=sys.stderr)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(to_yaml(imported, args.file.name))
    data = imported.data
    print(f"{args.out}: {len(data['sections'])} sections, {len(data['nodes'])} nodes, "
          f"{sum(len(v) for s in data['sections'] for v in s.get('equipment', {}).values())} items of equipment, "
          f"anchor {data['geodetic']['latitude']}, {data['geodetic']['longitude']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
