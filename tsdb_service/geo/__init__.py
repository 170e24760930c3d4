"""Location handling: NGSI geo encodings normalised to GeoJSON."""
