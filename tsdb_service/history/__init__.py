"""History answers over the read seam, shared by every face that shows samples
(QuantumLeap's API, Grafana, the explorer, NGSI-LD's value decoding):
``service`` resolves series and reads rows, ``geo_matching`` and
``geo_masks`` turn a geo-query into the series and samples it keeps,
``valuepath`` reaches inside structured values."""
