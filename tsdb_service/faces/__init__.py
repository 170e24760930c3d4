"""The faces: each API the service answers with, over the read seam and the
``history`` layer. A face never imports another face (``tests/test_import_layers.py``)."""
