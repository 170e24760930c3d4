"""Geometry primitives: NGSI location encodings normalised to GeoJSON
(``encodings``), geo-query filters (``filter``), geodesic distances."""
