"""Camera and projector models, the calibration file, and their estimation from observations.

The lowest layer: `reconstruction` and the simulator in `drivers` import it; it imports neither.
"""
