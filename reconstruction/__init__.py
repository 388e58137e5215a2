"""Pattern geometry and decoding, labelling, triangulation, range maps.

May import `calibration` (models); never `drivers` or `rig`.
"""
