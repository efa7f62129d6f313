"""Parsers and validation of raw ray-tracer exports.

``ingest.wireless_insite`` reads Wireless InSite files, ``ingest.geojson`` and
``ingest.mesh`` other building sources; all produce ``schemas`` objects and
Arrow tables. ``ingest.pipeline.ingest_city`` is the recipe that turns a city
folder into validated tables.
"""
