"""thrustmap: calibrate multirotor thrust maps on a bench and correct them from flight logs."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("thrustmap")
except PackageNotFoundError:  # running from a source tree without an install
    __version__ = "0.0.0+unknown"
