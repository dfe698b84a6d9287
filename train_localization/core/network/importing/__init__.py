"""Real track data into the project's network (docs/network.md, "Importing OSM and railML"):

  osm.py        OpenStreetMap railway tagging (osmium)
  railml.py     railML 3 infrastructure (lxml)
  build.py      what either read -> nodes, sections, equipment; the notes of what is left out
  alignment.py  surveyed points -> constant-curvature segments through every point

CLI: ``python -m train_localization.tools.import_track FILE -o OUT.yaml``.
"""
