"""vprsnn-export: STDP place-recognition SNNs from training to fixed-point deployment."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("vprsnn-export")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0.0.0+unknown"
