"""The command line, the configuration, the acquisition loop and Rerun logging.

The top layer: imports `drivers`, `calibration` and `reconstruction`; none of them imports it.
"""

__version__ = "0.1.0"
