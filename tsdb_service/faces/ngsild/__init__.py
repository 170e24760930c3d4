"""The NGSI-LD temporal API (ETSI GS CIM 009, clauses 5.6.11-5.6.16, 6.18-6.24)."""
